-- LIBERO-Plus scored by category: per base suite × category (and, when the spec carries the
-- authors' difficulty labels, × difficulty) the success rate with its Wilson 95% interval and its
-- drop from the same policy's base rate, with a 95% interval for the difference. Then every
-- category pooled over the suites (the leaderboard's per-category numbers). Written to
-- outputs/generalisation.csv by `pipeline generalisation` and shown in the report.
--
-- The rows are those of a LIBERO-Plus spec table (`pipeline specs --benchmark libero_plus`):
-- `benchmark = 'libero_plus'`, `category` the authors' category of the variant, and the base rows
-- (category null): the base tasks in LIBERO-Plus's own unperturbed env (its rounded nominal camera,
-- the same instruction mode), so a drop is the perturbation's alone. The base rate of a cell is
-- its suite's (pooled rows: every suite's base rows). The two rates are independent samples; the
-- interval is Newcombe's hybrid score interval (method 10 of Newcombe 1998) from the two Wilson
-- intervals: lo = d − √((p_b − l_b)² + (u_p − p_p)²), hi = d + √((u_b − p_b)² + (p_p − l_p)²).
-- `published`: the LIBERO-Plus leaderboard's rates for the category (all suites pooled,
-- data/published_libero.csv).
CREATE OR REPLACE VIEW generalisation AS
WITH plus AS (
    SELECT base_suite, category, difficulty, scored_success, success_definition, episode_length_cap,
           instruction_mode
    FROM scored
    WHERE benchmark = 'libero_plus'
),
base AS (
    SELECT base_suite, count(*) AS n_total, sum(CAST(scored_success AS BIGINT)) AS n_success
    FROM plus WHERE category IS NULL GROUP BY base_suite
    UNION ALL
    SELECT 'all', count(*), sum(CAST(scored_success AS BIGINT)) FROM plus WHERE category IS NULL
),
cells AS (
    SELECT base_suite, category, CAST(NULL AS INT) AS difficulty, count(*) AS n_total,
           sum(CAST(scored_success AS BIGINT)) AS n_success
    FROM plus WHERE category IS NOT NULL GROUP BY base_suite, category
    UNION ALL
    SELECT 'all', category, NULL, count(*), sum(CAST(scored_success AS BIGINT))
    FROM plus WHERE category IS NOT NULL GROUP BY category
    UNION ALL
    SELECT 'all', category, difficulty, count(*), sum(CAST(scored_success AS BIGINT))
    FROM plus WHERE category IS NOT NULL AND difficulty IS NOT NULL GROUP BY category, difficulty
),
published_cells AS (
    SELECT lower(perturbation) AS category,
           string_agg(model || ' ' || CAST(success_rate AS VARCHAR), '; ' ORDER BY model) AS published
    FROM published
    WHERE benchmark = 'libero-plus' AND suite IS NULL
    GROUP BY 1
),
rated AS (
    SELECT c.base_suite, c.category, c.difficulty, c.n_total, c.n_success,
           CAST(c.n_success AS DOUBLE) / c.n_total AS p, wilson_lo(c.n_success, c.n_total) AS l,
           wilson_hi(c.n_success, c.n_total) AS u,
           b.n_total AS base_n, CAST(b.n_success AS DOUBLE) / b.n_total AS pb,
           wilson_lo(b.n_success, b.n_total) AS lb, wilson_hi(b.n_success, b.n_total) AS ub,
           pc.published
    FROM cells c
    LEFT JOIN base b ON b.base_suite = c.base_suite
    LEFT JOIN published_cells pc ON pc.category = lower(c.category) AND c.base_suite = 'all' AND c.difficulty IS NULL
)
SELECT base_suite,
       category,
       difficulty,
       n_total,
       n_success,
       p AS success_rate,
       l AS ci_lo,
       u AS ci_hi,
       base_n,
       pb AS base_rate,
       pb - p AS drop_from_base,
       pb - p - sqrt(power(pb - lb, 2) + power(u - p, 2)) AS drop_lo,
       pb - p + sqrt(power(ub - pb, 2) + power(p - l, 2)) AS drop_hi,
       (SELECT min(success_definition) FROM plus) AS success_definition,
       (SELECT max(episode_length_cap) FROM plus) AS episode_cap,
       (SELECT min(instruction_mode) FROM plus) AS instruction_mode,
       published
FROM rated;

SELECT * FROM generalisation
ORDER BY CASE WHEN base_suite = 'all' THEN 1 ELSE 0 END, base_suite,
         CASE category WHEN 'Camera' THEN 1 WHEN 'Robot' THEN 2 WHEN 'Language' THEN 3 WHEN 'Light' THEN 4
                       WHEN 'Background' THEN 5 WHEN 'Noise' THEN 6 WHEN 'Layout' THEN 7 ELSE 8 END,
         difficulty NULLS FIRST;
