-- This run's success per suite beside the published LIBERO numbers (`published`, from
-- data/published_libero.csv), with every protocol difference named: a published number measured
-- with other trials per task, another episode cap, wait steps or success definition is not the
-- same quantity, and the report says so next to it. Used by `pipeline report`.
WITH run AS (
    SELECT suite,
           min(policy) AS policy,
           min(success_definition) AS success_definition,
           count(*) AS n_total,
           sum(CAST(scored_success AS BIGINT)) AS n_success,
           max(episode_length_cap) AS episode_cap,
           min(num_steps_wait) AS wait_steps,
           CAST(count(*) / count(DISTINCT task_id) AS INT) AS trials_per_task,
           count(DISTINCT task_id) AS n_tasks
    FROM scored
    GROUP BY suite
)
SELECT r.suite,
       r.policy,
       CAST(r.n_success AS DOUBLE) / r.n_total AS success_rate,
       wilson_lo(r.n_success, r.n_total) AS ci_lo,
       wilson_hi(r.n_success, r.n_total) AS ci_hi,
       r.n_total,
       p.model AS published_model,
       p.variant AS published_variant,
       p.reported_by,
       p.success_rate AS published_rate,
       p.success_rate BETWEEN wilson_lo(r.n_success, r.n_total) AND wilson_hi(r.n_success, r.n_total)
           AS published_rate_in_ci,
       concat_ws('; ',
           CASE WHEN r.n_tasks <> 10 THEN r.n_tasks || ' of the 10 tasks' END,
           CASE WHEN p.trials_per_task IS NULL THEN 'trials per task not stated'
                WHEN p.trials_per_task <> r.trials_per_task
                THEN 'trials per task ' || p.trials_per_task || ' published vs ' || r.trials_per_task || ' here' END,
           CASE WHEN p.episode_cap IS NULL THEN 'episode cap not stated'
                WHEN p.episode_cap <> r.episode_cap
                THEN 'episode cap ' || p.episode_cap || ' published vs ' || r.episode_cap || ' here' END,
           CASE WHEN p.wait_steps IS NOT NULL AND p.wait_steps <> r.wait_steps
                THEN 'wait steps ' || p.wait_steps || ' published vs ' || r.wait_steps || ' here' END,
           CASE WHEN p.success_definition IS NULL THEN 'success definition not stated'
                WHEN p.success_definition <> r.success_definition
                THEN 'success ' || p.success_definition || ' published vs ' || r.success_definition || ' here' END
       ) AS protocol_differences,
       p.source
FROM run r
JOIN published p ON p.suite = r.suite AND p.benchmark = 'libero'
ORDER BY r.suite, p.success_rate DESC, p.model
