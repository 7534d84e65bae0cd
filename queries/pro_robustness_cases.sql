-- LIBERO-PRO's robustness cases scored: per base suite × case (then all suites pooled) the
-- success rate with its Wilson 95% interval and the paired drop from the same policy's base rate.
-- Written to outputs/pro_robustness_cases.csv by `pipeline generalisation` and shown in the report.
--
-- The rows are those of `pipeline specs --benchmark libero-pro-robustness`:
-- `benchmark = 'libero_pro_robustness'`, `category` the case (visual_noise_glare,
-- camera_view_angle, runtime_object_move, object_texture, initial_pose_position_angle), and the
-- base rows (category null): the same task, init state and seed, unperturbed.
--
-- Pairing. Each case row's twin is the base row of the same (base suite, task, init state, seed)
-- (view_occlusion rows run the task's occluder scene, suite <suite>_view_occlusion: the base suite joins them). When
-- every row of a cell has its twin (`paired`), the base rate is the twins' and the interval for the
-- drop is Newcombe's paired method 10, with McNemar's exact p; otherwise the base rate is all of
-- the suite's base rows and the interval Newcombe's hybrid score interval for independent
-- proportions. `n_errors` / `base_n_errors`: episodes that ended in an error row (failures in
-- the rates).
WITH pro AS (
    SELECT suite, base_suite, task_id, init_state_id, seed, category, scored_success, errored
    FROM scored
    WHERE benchmark = 'libero_pro_robustness'
),
cases AS (
    SELECT p.base_suite, p.category, p.scored_success AS s, b.scored_success AS t, p.errored AS e, b.errored AS te
    FROM (SELECT * FROM pro WHERE category IS NOT NULL) p
    LEFT JOIN (SELECT * FROM pro WHERE category IS NULL) b
      ON b.base_suite = p.base_suite AND b.task_id = p.task_id AND b.init_state_id = p.init_state_id AND b.seed = p.seed
),
suite_base AS (
    SELECT base_suite, count(*) AS n_total, sum(CAST(scored_success AS BIGINT)) AS n_success,
           count(*) FILTER (WHERE errored) AS n_errors
    FROM pro WHERE category IS NULL GROUP BY base_suite
    UNION ALL
    SELECT 'all', count(*), sum(CAST(scored_success AS BIGINT)), count(*) FILTER (WHERE errored)
    FROM pro WHERE category IS NULL
),
grouped AS (
    SELECT base_suite, category, s, t, e, te FROM cases
    UNION ALL
    SELECT 'all', category, s, t, e, te FROM cases
),
cells AS (
    SELECT base_suite, category,
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
    GROUP BY base_suite, category
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
           wilson_hi(b.n_success, b.n_total) AS ub
    FROM cells c
    LEFT JOIN suite_base b ON b.base_suite = c.base_suite
)
SELECT base_suite,
       category AS robustness_case,
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
       suite_base_n
FROM rated
ORDER BY CASE WHEN base_suite = 'all' THEN 1 ELSE 0 END, base_suite,
         CASE category WHEN 'visual_noise_glare' THEN 1 WHEN 'camera_view_angle' THEN 2
                       WHEN 'runtime_object_move' THEN 3 WHEN 'object_texture' THEN 4
                       WHEN 'initial_pose_position_angle' THEN 5 WHEN 'view_occlusion' THEN 6 ELSE 7 END;
