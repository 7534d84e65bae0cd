-- Failure modes per suite and policy: how many failed episodes each primary mode accounts for,
-- and its share of the suite's episodes and of its failures (`queries/failure_modes.sql` defines
-- the modes). Harness faults (error, init_drift, saturated_actions) are flagged: they say
-- something about the set-up, not the policy.
WITH totals AS (
    SELECT suite, policy, count(*) AS n_episodes, sum(CASE WHEN scored_success THEN 0 ELSE 1 END) AS n_failed
    FROM scored GROUP BY suite, policy
)
SELECT f.suite, f.policy, f.failure_mode,
       f.failure_mode IN ('error', 'init_drift', 'saturated_actions') AS harness_fault,
       count(*) AS n,
       t.n_failed,
       t.n_episodes,
       round(CAST(count(*) AS DOUBLE) / t.n_failed, 4) AS share_of_failures,
       round(CAST(count(*) AS DOUBLE) / t.n_episodes, 4) AS share_of_episodes,
       min(f.success_definition) AS success_definition
FROM failure_modes f
JOIN totals t ON t.suite = f.suite AND t.policy = f.policy
GROUP BY f.suite, f.policy, f.failure_mode, t.n_failed, t.n_episodes
ORDER BY f.suite, f.policy, n DESC, f.failure_mode
