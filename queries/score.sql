-- One row per episode: its outcome under one success definition and one episode cap, derived
-- from the goal's stored evidence (never from a stored verdict), so a finished run can be
-- re-scored without re-simulating, reading one row per episode.
--
-- The evidence is `episodes.goal_changes`: the policy steps at which the goal's value changed
-- (before policy step 0 it counts as false), written by the rollout from the same values as the
-- step rows. `goal_held_at(goal_changes, p)` is the goal at policy step p. The same view derived
-- from the step rows, the ground truth, is `score_from_steps.sql`; the tests hold them equal on
-- real runs, and runs written before tables v3 (no evidence) are scored by that one.
--
-- Parameters, substituted and validated by `pipeline results` / `pipeline sql`:
--   {{success}}  'any-step'  : the goal held at some policy step within the cap (what the
--                              published scripts report: they stop at the first success);
--                'last-step' : the goal held at the last policy step within the cap, and the
--                              episode did not end early with an error before the cap.
--   {{cap}}      a cap in policy steps applied on top of each episode's own cap, or NULL.
-- Wait steps never count, as in the published loop.
CREATE OR REPLACE VIEW scored AS
WITH capped AS (
    -- runs before tables v4 have no base_suite/perturbation; they could only run LIBERO suites
    SELECT e.* EXCLUDE (base_suite, perturbation),
           COALESCE(e.base_suite, e.suite) AS base_suite,
           COALESCE(e.perturbation, 'none') AS perturbation,
           CAST(LEAST(e.max_steps, COALESCE({{cap}}, e.max_steps)) AS INT) AS episode_length_cap
    FROM episodes e
)
SELECT c.*,
       '{{success}}' AS success_definition,
       -- an error counts only if it cut the episode short of the cap
       (c.error_kind IS NOT NULL AND c.n_policy_steps < c.episode_length_cap) AS errored,
       CASE '{{success}}'
           -- the goal first turned true before the cap (the list is ascending)
           WHEN 'any-step' THEN COALESCE(c.goal_changes[1] < c.episode_length_cap, false)
           -- the goal at the last policy step run within the cap
           ELSE COALESCE(goal_held_at(c.goal_changes, LEAST(c.n_policy_steps, c.episode_length_cap) - 1), false)
                AND (c.error_kind IS NULL OR c.n_policy_steps >= c.episode_length_cap)
       END AS scored_success
FROM capped c;
