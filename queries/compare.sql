-- Paired comparison of runs A and B per suite, and over all suites (suite = 'all'), from the
-- `pairs` view (queries/compare_pairs.sql). Written to outputs/compare.csv by `pipeline compare`.
--
-- On the paired episodes: n_both (both succeed), n_a_only (A only: McNemar's b), n_b_only (B
-- only: c), n_neither; the success rates, their difference B − A = (c − b)/n, its 95% interval
-- (Newcombe 1998 method 10, paired: newcombe_paired_lo/hi with B as the first run) and the exact
-- McNemar p-value (two-sided binomial test of b against b + c). n_only_in_a / n_only_in_b count
-- the episode keys that only one run has; they are not in any other number.
WITH counts AS (
    SELECT COALESCE(suite, 'all') AS suite_or_all,
           min(policy_a) AS policy_a,
           min(policy_b) AS policy_b,
           min(success_definition) AS success_definition,
           max(episode_length_cap_a) AS episode_length_cap_a,
           max(episode_length_cap_b) AS episode_length_cap_b,
           count(*) FILTER (WHERE paired) AS n_paired,
           count(*) FILTER (WHERE paired AND success_a AND success_b) AS n_both,
           count(*) FILTER (WHERE paired AND success_a AND NOT success_b) AS n_a_only,
           count(*) FILTER (WHERE paired AND NOT success_a AND success_b) AS n_b_only,
           count(*) FILTER (WHERE paired AND NOT success_a AND NOT success_b) AS n_neither,
           count(*) FILTER (WHERE success_b IS NULL) AS n_only_in_a,
           count(*) FILTER (WHERE success_a IS NULL) AS n_only_in_b
    FROM pairs
    GROUP BY ROLLUP (suite)
)
SELECT suite_or_all AS suite,
       policy_a,
       policy_b,
       success_definition,
       episode_length_cap_a,
       episode_length_cap_b,
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
ORDER BY suite_or_all = 'all', suite_or_all;
