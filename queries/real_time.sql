-- A real-time run (`pipeline run --latency-ms`): how much of each suite's policy time ran the hold
-- action because the policy's answer was late (steps.held; vla-eval's stale_action_ratio), and how
-- late the first action came. Held steps are policy steps: they spend the episode's cap.
-- `pipeline run` and `pipeline results` print it for a real-time run; on a closed-loop run every
-- share is 0.
WITH policy_steps AS (
    SELECT suite, episode_key, policy_step, coalesce(held, false) AS held
    FROM steps WHERE policy_step IS NOT NULL
),
first_action AS (
    SELECT suite, episode_key, min(policy_step) AS first_step
    FROM policy_steps WHERE NOT held GROUP BY suite, episode_key
)
SELECT
    p.suite,
    count(DISTINCT p.episode_key) AS episodes,
    count(*) AS policy_steps,
    sum(CASE WHEN p.held THEN 1 ELSE 0 END) AS held_steps,
    round(avg(CASE WHEN p.held THEN 1.0 ELSE 0.0 END), 4) AS held_share,
    (SELECT round(avg(f.first_step), 2) FROM first_action f WHERE f.suite = p.suite) AS mean_first_action_step
FROM policy_steps p
GROUP BY p.suite
ORDER BY p.suite;
