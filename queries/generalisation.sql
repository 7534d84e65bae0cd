-- LIBERO-Plus scored by category: per base suite × category (and, all suites pooled, per category ×
-- difficulty when the spec carries the authors' labels) the success rate with its Wilson 95% interval and its
-- drop from the same policy's base rate, with a 95% interval for the difference. Then every
-- category pooled over the suites (the leaderboard's per-category numbers). Written to
-- outputs/generalisation.csv by `pipeline generalisation` and shown in the report.
--
-- The rows are those of a LIBERO-Plus spec table (`pipeline specs --benchmark libero-plus`):
-- `benchmark = 'libero_plus'`, `category` the authors' category of the variant, and the base rows
-- (category null): the base tasks in LIBERO-Plus's own unperturbed env (its rounded nominal camera,
-- the same instruction mode).
--
-- Pairing. Every variant starts from init state 0 of its base task, so its twin is the base row of
-- the same (task, init state, seed) and instruction mode: the same start, unperturbed. When every variant of a cell has
-- its twin (`paired`; base rows with --base-trials ≥ 1 give them), the base rate is the twins' and
-- the interval for the drop is Newcombe's paired method 10; the drop then measures the
-- perturbation alone, not the difference between init state 0 and the others. Otherwise the base
-- rate is all of the suite's base rows and the interval Newcombe's hybrid score interval for
-- independent proportions: lo = d − √((p_b − l_b)² + (u_p − p_p)²), hi = d + √((u_b − p_b)² + (p_p − l_p)²).
-- `suite_base_rate` is always all of the suite's base rows (e.g. 50 init states per task).
-- Errors. An episode that ended in an error row before its cap (`errored`, queries/score.sql)
-- counts as a failure, as everywhere; `n_errors` says how many of a cell's `n_total` variants did,
-- and `base_n_errors` how many of the base rows behind `base_rate` (`suite_base_n_errors`: of all
-- the suite's base rows), so a rate never silently stands for fewer episodes than were run.
-- `published`: the LIBERO-Plus leaderboard's rates for the category (all suites pooled,
-- data/published_libero.csv).
CREATE OR REPLACE VIEW generalisation AS
WITH plus AS (
    SELECT base_suite, task_id, init_state_id, seed, category, difficulty, scored_success, errored,
           success_definition, episode_length_cap, instruction_mode
    FROM scored
    WHERE benchmark = 'libero_plus'
),
variants AS (
    -- each variant with its twin's outcome (null when the run has no twin for it)
    SELECT p.base_suite, p.category, p.difficulty, p.scored_success AS s, b.scored_success AS t,
           p.errored AS e, b.errored AS te
    FROM (SELECT * FROM plus WHERE category IS NOT NULL) p
    LEFT JOIN (SELECT * FROM plus WHERE category IS NULL) b
      ON b.base_suite = p.base_suite AND b.task_id = p.task_id AND b.init_state_id = p.init_state_id
     AND b.seed = p.seed AND b.instruction_mode = p.instruction_mode
),
suite_base AS (
    SELECT base_suite, count(*) AS n_total, sum(CAST(scored_success AS BIGINT)) AS n_success,
           count(*) FILTER (WHERE errored) AS n_errors
    FROM plus WHERE category IS NULL GROUP BY base_suite
    UNION ALL
    SELECT 'all', count(*), sum(CAST(scored_success AS BIGINT)), count(*) FILTER (WHERE errored)
    FROM plus WHERE category IS NULL
),
grouped AS (
    SELECT base_suite, category, CAST(NULL AS INT) AS difficulty, s, t, e, te FROM variants
    UNION ALL
    SELECT 'all', category, NULL, s, t, e, te FROM variants
    UNION ALL
    SELECT 'all', category, difficulty, s, t, e, te FROM variants WHERE difficulty IS NOT NULL
),
cells AS (
    SELECT base_suite, category, difficulty,
           count(*) AS n_total,
           sum(CAST(s AS BIGINT)) AS n_success,
           count(*) FILTER (WHERE e) AS n_errors,
           count(t) AS n_pairs,
           count(*) FILTER (WHERE te) AS twin_n_errors,
           count(*) FILTER (WHERE t AND s) AS n11,
           count(*) FILTER (WHERE t AND NOT s) AS n10,
           count(*) FILTER (WHERE NOT t AND s) AS n01,
           count(*) FILTER (WHERE NOT t AND NOT s) AS n00
    FROM grouped
    GROUP BY base_suite, category, difficulty
),
published_cells AS (
    SELECT lower(perturbation) AS category,
           string_agg(model || ' ' || CAST(success_rate AS VARCHAR), '; ' ORDER BY model) AS published
    FROM published
    WHERE benchmark = 'libero-plus' AND suite IS NULL
    GROUP BY 1
),
rated AS (
    SELECT c.*,
           c.n_pairs = c.n_total AS paired,
           CAST(c.n_success AS DOUBLE) / c.n_total AS p,
           wilson_lo(c.n_success, c.n_total) AS l,
           wilson_hi(c.n_success, c.n_total) AS u,
           b.n_total AS suite_base_n,
           b.n_errors AS suite_base_n_errors,
           CAST(b.n_success AS DOUBLE) / b.n_total AS pb,
           wilson_lo(b.n_success, b.n_total) AS lb,
           wilson_hi(b.n_success, b.n_total) AS ub,
           pc.published
    FROM cells c
    LEFT JOIN suite_base b ON b.base_suite = c.base_suite
    LEFT JOIN published_cells pc ON pc.category = lower(c.category) AND c.base_suite = 'all' AND c.difficulty IS NULL
)
SELECT base_suite,
       category,
       difficulty,
       n_total,
       n_success,
       n_errors,
       p AS success_rate,
       l AS ci_lo,
       u AS ci_hi,
       paired,
       CASE WHEN paired THEN CAST(n11 + n10 AS DOUBLE) / n_pairs ELSE pb END AS base_rate,
       CASE WHEN paired THEN n_pairs ELSE suite_base_n END AS base_n,
       CASE WHEN paired THEN twin_n_errors ELSE suite_base_n_errors END AS base_n_errors,
       CASE WHEN paired THEN CAST(n10 - n01 AS DOUBLE) / n_pairs ELSE pb - p END AS drop_from_base,
       CASE WHEN paired THEN newcombe_paired_lo(n11, n10, n01, n00)
            ELSE pb - p - sqrt(power(pb - lb, 2) + power(u - p, 2)) END AS drop_lo,
       CASE WHEN paired THEN newcombe_paired_hi(n11, n10, n01, n00)
            ELSE pb - p + sqrt(power(ub - pb, 2) + power(p - l, 2)) END AS drop_hi,
       CASE WHEN paired AND n01 + n10 > 0 THEN mcnemar_exact_p(n01, n10) END AS mcnemar_p,
       n11, n10, n01, n00,
       pb AS suite_base_rate,
       suite_base_n,
       suite_base_n_errors,
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
