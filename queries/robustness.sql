-- LIBERO-PRO scored beside the base suites: per base suite × perturbation the success rate with
-- its Wilson 95% interval, and its drop from the base suite's rate with a 95% interval for the
-- difference (base − perturbed). The base rate of a perturbed cell is the base suite's over the
-- same tasks (`base_n` episodes; over the pairs when paired), so a run of a few tasks compares like
-- with like. Written to outputs/robustness.csv by `pipeline robustness` and
-- shown in the report. Reads the `scored` view, so every success definition and cap applies.
--
-- Pairing, from the data: a perturbed episode pairs with the base episode of the same (task,
-- init_state_id, seed) when both start from the same state (`episodes.start_sha256`: scene,
-- fixture poses, init state). A cell whose every episode has such a twin is `paired`: its
-- interval is Newcombe's paired method 10 over the pairs. Otherwise the two rates are independent
-- samples, and the interval is Newcombe's hybrid score interval for independent proportions
-- (method 10 of Newcombe 1998, "Interval estimation for the difference between independent
-- proportions"), from the two Wilson intervals:
--   lo = d − √((p_b − l_b)² + (u_p − p_p)²),   hi = d + √((u_b − p_b)² + (p_p − l_p)²).
-- LIBERO-PRO's shipped suites pair with nothing: all 16 were given new init states (the robot at
-- its nominal joint pose, the objects re-placed), `_lan` included, though its scene and fixture
-- poses are the base's (tests/pro.rs). A variant that only changes the instruction would pair.
--
-- `instruction_changed`: the fraction of the cell's tasks whose policy got another instruction
-- text than on the base task; under `--instruction published` a
-- `swap`/`object` task gets the BDDL text while its base task gets the file-name text, so its
-- drop mixes the perturbation with that change (run both with `--instruction bddl` to separate
-- them). `published`: the LIBERO-PRO leaderboard's rates for the cell (data/published_libero.csv;
-- the authors call swap "position", lan "semantic", env "environment").
-- LIBERO-Plus's layout suites (`perturbation = 'plus_layout'`, `<suite>_plus_layout`) are not LIBERO-PRO:
-- `generalisation` scores them, with the rest of LIBERO-Plus; they are left out here.
CREATE OR REPLACE VIEW robustness AS
WITH pro AS (
    SELECT * FROM scored WHERE perturbation <> 'plus_layout'
),
cells AS (
    SELECT base_suite,
           perturbation,
           count(*) AS n_total,
           sum(CAST(scored_success AS BIGINT)) AS n_success,
           count(DISTINCT task_id) AS n_tasks,
           min(success_definition) AS success_definition,
           max(episode_length_cap) AS episode_cap,
           min(instruction_source) AS instruction_source
    FROM pro
    GROUP BY base_suite, perturbation
),
-- the base suite's episodes on the same tasks as each perturbed cell (a run may hold a subset)
base AS (
    SELECT t.base_suite,
           t.perturbation,
           count(*) AS n_total,
           sum(CAST(b.scored_success AS BIGINT)) AS n_success
    FROM (SELECT DISTINCT base_suite, perturbation, task_id FROM pro WHERE perturbation <> 'none') t
    JOIN pro b ON b.base_suite = t.base_suite AND b.task_id = t.task_id AND b.perturbation = 'none'
    GROUP BY t.base_suite, t.perturbation
    UNION ALL
    SELECT base_suite, perturbation, n_total, n_success FROM cells WHERE perturbation = 'none'
),
pairs AS (
    SELECT p.base_suite,
           p.perturbation,
           count(*) AS n_pairs,
           count(*) FILTER (WHERE b.scored_success AND p.scored_success) AS n11,
           count(*) FILTER (WHERE b.scored_success AND NOT p.scored_success) AS n10,
           count(*) FILTER (WHERE NOT b.scored_success AND p.scored_success) AS n01,
           count(*) FILTER (WHERE NOT b.scored_success AND NOT p.scored_success) AS n00
    FROM pro p
    JOIN pro b
      ON b.base_suite = p.base_suite AND b.perturbation = 'none'
     AND b.task_id = p.task_id AND b.init_state_id = p.init_state_id AND b.seed = p.seed
     AND b.start_sha256 = p.start_sha256
    WHERE p.perturbation <> 'none'
    GROUP BY p.base_suite, p.perturbation
),
task_instructions AS (
    -- per (base suite, perturbation, task): did the policy get another text than on the base task?
    SELECT p.base_suite, p.perturbation,
           avg(CASE WHEN b.instruction <> p.instruction THEN 1.0 ELSE 0.0 END) AS instruction_changed
    FROM (SELECT DISTINCT base_suite, perturbation, task_id, instruction FROM pro WHERE perturbation <> 'none') p
    JOIN (SELECT DISTINCT base_suite, task_id, instruction FROM pro WHERE perturbation = 'none') b
      ON b.base_suite = p.base_suite AND b.task_id = p.task_id
    GROUP BY p.base_suite, p.perturbation
),
published_cells AS (
    SELECT suite AS base_suite,
           CASE perturbation WHEN 'position' THEN 'swap' WHEN 'semantic' THEN 'lan'
                             WHEN 'environment' THEN 'env' ELSE perturbation END AS perturbation,
           string_agg(model || ' ' || CAST(success_rate AS VARCHAR), '; ' ORDER BY model) AS published
    FROM published
    WHERE benchmark = 'libero-pro' AND suite IS NOT NULL
    GROUP BY 1, 2
),
rows AS (
    SELECT c.base_suite,
           c.perturbation,
           c.perturbation <> 'none' AND COALESCE(pr.n_pairs, 0) = c.n_total AS paired,
           c.n_tasks,
           c.n_total,
           c.n_success,
           CAST(c.n_success AS DOUBLE) / c.n_total AS success_rate,
           wilson_lo(c.n_success, c.n_total) AS ci_lo,
           wilson_hi(c.n_success, c.n_total) AS ci_hi,
           -- paired: the base's rate over the pairs; else over the base's episodes of the same tasks
           CASE WHEN c.perturbation <> 'none' AND COALESCE(pr.n_pairs, 0) = c.n_total
                THEN CAST(pr.n11 + pr.n10 AS DOUBLE) / NULLIF(pr.n_pairs, 0)
                ELSE CAST(b.n_success AS DOUBLE) / b.n_total END AS base_rate,
           b.n_total AS base_n,
           wilson_lo(b.n_success, b.n_total) AS base_lo,
           wilson_hi(b.n_success, b.n_total) AS base_hi,
           pr.n_pairs, pr.n11, pr.n10, pr.n01, pr.n00,
           ti.instruction_changed,
           c.success_definition,
           c.episode_cap,
           c.instruction_source,
           pc.published
    FROM cells c
    LEFT JOIN base b ON b.base_suite = c.base_suite AND b.perturbation = c.perturbation
    LEFT JOIN pairs pr ON pr.base_suite = c.base_suite AND pr.perturbation = c.perturbation
    LEFT JOIN task_instructions ti ON ti.base_suite = c.base_suite AND ti.perturbation = c.perturbation
    LEFT JOIN published_cells pc ON pc.base_suite = c.base_suite AND pc.perturbation = c.perturbation
)
SELECT base_suite,
       perturbation,
       paired,
       n_tasks,
       n_total,
       n_success,
       success_rate,
       ci_lo,
       ci_hi,
       base_rate,
       base_n,
       CASE WHEN perturbation = 'none' THEN NULL
            WHEN paired THEN CAST(n10 - n01 AS DOUBLE) / NULLIF(n_pairs, 0)
            ELSE base_rate - success_rate END AS drop_from_base,
       CASE WHEN perturbation = 'none' THEN NULL
            WHEN paired THEN newcombe_paired_lo(n11, n10, n01, n00)
            ELSE (base_rate - success_rate)
                 - sqrt(power(base_rate - base_lo, 2) + power(ci_hi - success_rate, 2)) END AS drop_ci_lo,
       CASE WHEN perturbation = 'none' THEN NULL
            WHEN paired THEN newcombe_paired_hi(n11, n10, n01, n00)
            ELSE (base_rate - success_rate)
                 + sqrt(power(base_hi - base_rate, 2) + power(success_rate - ci_lo, 2)) END AS drop_ci_hi,
       n_pairs,
       CASE WHEN paired AND n01 + n10 > 0 THEN mcnemar_exact_p(n01, n10) END AS mcnemar_p,
       instruction_changed,
       success_definition,
       episode_cap,
       instruction_source,
       published,
       CASE WHEN perturbation = 'env'
            THEN 'generated locally by LIBERO-PRO''s own perturbator with our init states (the authors'' are not on PyPI): not comparable with the leaderboard''s environment column'
       END AS note
FROM rows;

SELECT * FROM robustness
ORDER BY base_suite, CASE perturbation WHEN 'none' THEN 0 WHEN 'swap' THEN 1 WHEN 'object' THEN 2
                                       WHEN 'lan' THEN 3 WHEN 'task' THEN 4 ELSE 5 END;
