-- One row per episode: its outcome under one success definition and one episode cap, derived
-- from the stored step rows, the ground truth. `score.sql` derives the same from the episodes'
-- compact goal evidence and is what the commands use; this one scores runs written before
-- tables v3, and the tests hold the two equal on real runs. To score any run from its steps,
-- copy queries/, put this file's text in score.sql and set LIBERO_QUERIES to that folder.
--
-- Parameters, substituted and validated by `pipeline results` / `pipeline sql`:
--   {{success}}  'any-step'  : the goal held at some policy step within the cap (what the
--                              published scripts report: they stop at the first success);
--                'last-step' : the goal held at the last policy step within the cap, and the
--                              episode did not end early with an error before the cap.
--   {{cap}}      a cap in policy steps applied on top of each episode's own cap, or NULL.
-- Wait steps (policy_step IS NULL) never count, as in the published loop.
CREATE OR REPLACE VIEW scored AS
WITH capped AS (
    -- runs before tables v4 have no base_suite/perturbation; they could only run LIBERO suites
    SELECT e.* EXCLUDE (base_suite, perturbation),
           COALESCE(e.base_suite, e.suite) AS base_suite,
           COALESCE(e.perturbation, 'none') AS perturbation,
           CAST(LEAST(e.max_steps, COALESCE({{cap}}, e.max_steps)) AS INT) AS episode_length_cap
    FROM episodes e
),
per_episode AS (
    SELECT s.episode_key,
           bool_or(s.goal) AS any_goal,
           max(s.policy_step) AS last_step
    FROM steps s
    JOIN capped c ON s.episode_key = c.episode_key
    WHERE s.policy_step IS NOT NULL AND s.policy_step < c.episode_length_cap
    GROUP BY s.episode_key
),
last_goal AS (
    SELECT p.episode_key, s.goal AS last_goal
    FROM per_episode p
    JOIN steps s ON s.episode_key = p.episode_key AND s.policy_step = p.last_step
)
SELECT c.*,
       '{{success}}' AS success_definition,
       -- an error counts only if it cut the episode short of the cap
       (c.error_kind IS NOT NULL AND c.n_policy_steps < c.episode_length_cap) AS errored,
       CASE '{{success}}'
           WHEN 'any-step' THEN COALESCE(p.any_goal, false)
           ELSE COALESCE(l.last_goal, false)
                AND (c.error_kind IS NULL OR c.n_policy_steps >= c.episode_length_cap)
       END AS scored_success
FROM capped c
LEFT JOIN per_episode p ON p.episode_key = c.episode_key
LEFT JOIN last_goal l ON l.episode_key = c.episode_key;
