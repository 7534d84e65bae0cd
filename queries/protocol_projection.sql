-- The canonical protocol's wall time at the episode lengths of a policy that succeeds, at a measured
-- rate (`pipeline bench run --run RUN --lengths LENGTHS_RUN`). Over LENGTHS_RUN's `episodes`.
--
-- A model with random weights never succeeds, so its run goes to the caps; a good policy's episodes
-- stop at their first success (the published loops' `done` → break; here `pipeline run
-- --stop-on-success`). Each suite's 500 episodes (10 tasks x 50 trials) are projected as: with
-- probability {{success_rate}}, the mean length of LENGTHS_RUN's successful episodes of that suite
-- (first_success_step + 1 policy steps: the step that succeeded is the last one run); otherwise the
-- canonical cap (220, 280, 300, 520; a failure runs to it). LENGTHS_RUN is a stored run of a policy
-- that succeeds, such as the scripted expert's over the four suites, best at the canonical caps: a
-- success at or after a suite's canonical cap is none there and does not count, and a run with
-- smaller caps misses its late successes. Only LENGTHS_RUN's unperturbed, error-free episodes are
-- read; its success rate does not enter (the lengths are of the tasks it solves). The policy steps
-- are divided by {{policy_steps_per_s}}, the rate of the measured run (queries/step_timing.sql); the
-- 10 wait steps per episode (no policy query, no render) are left out. A suite without a successful
-- episode in LENGTHS_RUN has no projection (unless {{success_rate}} is 0), and then neither has the
-- total.
WITH canonical(suite, position, cap) AS (
    VALUES ('libero_spatial', 1, 220), ('libero_object', 2, 280), ('libero_goal', 3, 300), ('libero_10', 4, 520)
),
lengths AS (
    -- runs before tables v4 have no base_suite/perturbation; they could only run LIBERO suites
    SELECT
        COALESCE(e.base_suite, e.suite) AS suite,
        COUNT(*) AS episodes,
        SUM(CASE WHEN e.success AND e.first_success_step < c.cap THEN 1 ELSE 0 END) AS successes,
        AVG(CASE WHEN e.success AND e.first_success_step < c.cap THEN e.first_success_step + 1 END) AS mean_success_steps
    FROM episodes e JOIN canonical c ON c.suite = COALESCE(e.base_suite, e.suite)
    WHERE COALESCE(e.perturbation, 'none') = 'none' AND e.error_kind IS NULL
    GROUP BY COALESCE(e.base_suite, e.suite)
),
per_suite AS (
    SELECT
        c.suite,
        c.position,
        COALESCE(l.episodes, 0) AS episodes,
        COALESCE(l.successes, 0) AS successes,
        l.mean_success_steps,
        c.cap,
        CASE
            WHEN {{success_rate}} = 0 THEN 500.0 * c.cap
            ELSE 500.0 * ({{success_rate}} * l.mean_success_steps + (1.0 - {{success_rate}}) * c.cap)
        END AS policy_steps
    FROM canonical c LEFT JOIN lengths l ON l.suite = c.suite
)
SELECT suite, episodes, successes, mean_success_steps, cap, policy_steps,
       policy_steps / {{policy_steps_per_s}} / 60.0 AS minutes
FROM (
    SELECT position, suite, episodes, successes, mean_success_steps, cap, policy_steps FROM per_suite
    UNION ALL
    SELECT
        5,
        'all four',
        SUM(episodes),
        SUM(successes),
        CAST(NULL AS DOUBLE),
        CAST(NULL AS BIGINT),
        CASE WHEN COUNT(policy_steps) = 4 THEN SUM(policy_steps) END
    FROM per_suite
)
ORDER BY position
