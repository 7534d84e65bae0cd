-- Success rate per task with Wilson 95% intervals, from the `scored` view (queries/score.sql).
-- Written to outputs/results_by_task.csv by `pipeline results`.
SELECT suite,
       task_id,
       min(instruction) AS instruction,
       min(policy) AS policy,
       min(success_definition) AS success_definition,
       count(*) AS n_total,
       sum(CAST(scored_success AS BIGINT)) AS n_success,
       sum(CAST(errored AS BIGINT)) AS n_error,
       avg(CAST(scored_success AS DOUBLE)) AS success_rate,
       wilson_lo(sum(CAST(scored_success AS BIGINT)), count(*)) AS ci_lo,
       wilson_hi(sum(CAST(scored_success AS BIGINT)), count(*)) AS ci_hi,
       max(episode_length_cap) AS episode_length_cap
FROM scored
GROUP BY suite, task_id
ORDER BY suite, task_id;
