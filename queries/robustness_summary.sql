-- The brief's question in one table: per base suite, its rate next to each perturbation's, the
-- mean drop over the perturbations run, the worst one, and which suite falls most; then the
-- LIBERO-PRO total as the authors compute it (the plain mean of the suite × perturbation cells,
-- base suites left out) beside their totals. Reads the view `robustness` (queries/robustness.sql).
-- Written to outputs/robustness_summary.csv by `pipeline robustness`.
WITH per_suite AS (
    SELECT base_suite,
           max(success_rate) FILTER (WHERE perturbation = 'none') AS base,
           max(success_rate) FILTER (WHERE perturbation = 'swap') AS swap,
           max(success_rate) FILTER (WHERE perturbation = 'object') AS object,
           max(success_rate) FILTER (WHERE perturbation = 'lan') AS lan,
           max(success_rate) FILTER (WHERE perturbation = 'task') AS task,
           max(success_rate) FILTER (WHERE perturbation = 'env') AS env,
           avg(drop_from_base) FILTER (WHERE perturbation <> 'none') AS mean_drop,
           count(*) FILTER (WHERE perturbation <> 'none') AS n_perturbations,
           -- the perturbation with the largest drop (ties: the first in swap, object, lan, task, env)
           first_value(perturbation ORDER BY drop_from_base DESC NULLS LAST) AS worst_perturbation,
           max(drop_from_base) AS worst_drop
    FROM robustness
    GROUP BY base_suite
),
ranked AS (
    SELECT p.*, rank() OVER (ORDER BY mean_drop DESC NULLS LAST) AS falls_most_rank FROM per_suite p
),
total AS (
    SELECT 'LIBERO-PRO total (this run)' AS base_suite,
           avg(success_rate) FILTER (WHERE perturbation <> 'none') AS total,
           count(*) FILTER (WHERE perturbation <> 'none') AS n_cells
    FROM robustness
)
SELECT r.base_suite, r.base, r.swap, r.object, r.lan, r.task, r.env, r.n_perturbations, r.mean_drop,
       r.worst_perturbation, r.worst_drop, r.falls_most_rank,
       CAST(NULL AS DOUBLE) AS libero_pro_total, CAST(NULL AS BIGINT) AS n_cells, CAST(NULL AS VARCHAR) AS note
FROM ranked r
UNION ALL
SELECT t.base_suite, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL,
       t.total, t.n_cells,
       'plain mean of the suite × perturbation cells, as the authors compute theirs (their 20 cells include env); '
       || 'published totals: ' || (SELECT string_agg(model || ' ' || CAST(success_rate AS VARCHAR), '; ' ORDER BY model)
                                   FROM published WHERE benchmark = 'libero-pro' AND perturbation = 'total')
FROM total t
ORDER BY falls_most_rank NULLS LAST, base_suite;
