-- Paired comparison of runs A and B per task, from the `pairs` view
-- (queries/compare_pairs.sql); the columns of queries/compare.sql. Written to
-- outputs/compare_by_task.csv by `pipeline compare`. With 50 trials per task, only large
-- differences are resolved: read mcnemar_p and the interval, not the difference alone.
WITH counts AS (
    SELECT suite,
           task_id,
           min(instruction) AS instruction,
           min(success_definition) AS success_definition,
           count(*) FILTER (WHERE paired) AS n_paired,
           count(*) FILTER (WHERE paired AND success_a AND success_b) AS n_both,
           count(*) FILTER (WHERE paired AND success_a AND NOT success_b) AS n_a_only,
           count(*) FILTER (WHERE paired AND NOT success_a AND success_b) AS n_b_only,
           count(*) FILTER (WHERE paired AND NOT success_a AND NOT success_b) AS n_neither,
           count(*) FILTER (WHERE success_b IS NULL) AS n_only_in_a,
           count(*) FILTER (WHERE success_a IS NULL) AS n_only_in_b
    FROM pairs
    GROUP BY suite, task_id
)
SELECT suite,
       task_id,
       instruction,
       success_definition,
       n_paired,
       n_both + n_a_only AS n_success_a,
       n_both + n_b_only AS n_success_b,
       n_both,
       n_a_only,
       n_b_only,
       n_neither,
       n_only_in_a,
       n_only_in_b,
       CAST(n_both + n_a_only AS DOUBLE) / NULLIF(n_paired, 0) AS success_rate_a,
       CAST(n_both + n_b_only AS DOUBLE) / NULLIF(n_paired, 0) AS success_rate_b,
       CAST(n_b_only - n_a_only AS DOUBLE) / NULLIF(n_paired, 0) AS diff_b_minus_a,
       newcombe_paired_lo(n_both, n_b_only, n_a_only, n_neither) AS diff_ci_lo,
       newcombe_paired_hi(n_both, n_b_only, n_a_only, n_neither) AS diff_ci_hi,
       CASE WHEN n_paired > 0 THEN mcnemar_exact_p(n_a_only, n_b_only) END AS mcnemar_p
FROM counts
ORDER BY suite, task_id;
