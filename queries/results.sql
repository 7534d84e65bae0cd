-- Success rate per suite with Wilson 95% intervals, from the `scored` view (queries/score.sql).
-- Written to outputs/results.csv by `pipeline results`. Errored episodes count as failures (as
-- in the published scripts, where an exception ends the trial) and are counted in n_error.
WITH per_task AS (
    SELECT suite, task_id, count(*) AS n
    FROM scored
    GROUP BY suite, task_id
),
per_suite_tasks AS (
    SELECT suite, count(*) AS n_tasks, min(n) AS n_min, max(n) AS n_max
    FROM per_task
    GROUP BY suite
)
SELECT s.suite,
       min(s.policy) AS policy,
       min(s.success_definition) AS success_definition,
       count(*) AS n_total,
       sum(CAST(s.scored_success AS BIGINT)) AS n_success,
       sum(CAST(s.errored AS BIGINT)) AS n_error,
       avg(CAST(s.scored_success AS DOUBLE)) AS success_rate,
       wilson_lo(sum(CAST(s.scored_success AS BIGINT)), count(*)) AS ci_lo,
       wilson_hi(sum(CAST(s.scored_success AS BIGINT)), count(*)) AS ci_hi,
       max(s.episode_length_cap) AS episode_length_cap,
       min(t.n_tasks) AS n_tasks,
       -- equal across tasks in a canonical run; the minimum otherwise (see n_rollouts_uneven)
       min(t.n_min) AS n_rollouts_per_task,
       min(t.n_min) <> min(t.n_max) AS n_rollouts_uneven
FROM scored s
JOIN per_suite_tasks t ON t.suite = s.suite
GROUP BY s.suite
ORDER BY s.suite;
