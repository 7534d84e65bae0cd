-- ALOHA-sim's failure modes: for every episode that failed under the `scored` view's success
-- definition and cap, one primary mode, derived from the stored steps' reward (gym-aloha's 0-4
-- contact stages, `tables::aloha_steps`). Defines the view `failure_modes` in an ALOHA-sim run's
-- session (a LIBERO run's is queries/failure_modes.sql); nothing runs until a query reads it.
--
-- The stages, transfer_cube (task_id 0): 1 the right gripper touches the cube, 2 it lifts it off
-- the table, 3 the left gripper touches it (cube on the table), 4 the left holds it off the table.
-- insertion (task_id 1): 1 both grippers touch their objects, 2 both lifted, 3 the peg touches the
-- socket (both off the table), 4 the peg touches the pin.
--
-- Modes, in order of precedence (the first that applies):
--   error              the episode ended early with an error row (an unstable simulation, a NaN
--                      action, a policy failure): a harness or policy crash, not a behaviour.
--   transient_success  reward 4 at some policy step within the cap but not at the last (only under
--                      last-step scoring: any-step counts these as successes).
--   dropped            lifted (reward >= 2) at some step, back down (reward < 2) at the last.
--   never_touched      transfer: the right gripper never touched the cube (reward 0 throughout).
--   not_lifted         transfer: touched, never lifted (at most 1).
--   not_transferred    transfer: lifted, never held by the left gripper off the table (2 or 3).
--   not_grasped        insertion: the two grippers never held both objects at once (0).
--   not_lifted         insertion: both grasped, never both lifted (at most 1).
--   not_aligned        insertion: both lifted, the peg never touched the socket (at most 2).
--   not_inserted       insertion: the peg touched the socket, never the pin (3).
CREATE OR REPLACE VIEW aloha_failure_evidence AS
WITH capped AS (
    SELECT s.episode_key, s.policy_step, s.reward, c.episode_length_cap, c.n_policy_steps
    FROM steps s
    JOIN scored c ON c.episode_key = s.episode_key
    WHERE s.policy_step < c.episode_length_cap
),
last AS (
    SELECT episode_key, max(policy_step) AS last_step FROM capped GROUP BY episode_key
)
SELECT c.episode_key,
       max(c.reward) AS max_reward,
       max(CASE WHEN c.policy_step = l.last_step THEN c.reward END) AS final_reward,
       min(CASE WHEN c.reward >= 2 THEN c.policy_step END) AS first_lift_step,
       min(CASE WHEN c.reward = 4 THEN c.policy_step END) AS first_success_step
FROM capped c
JOIN last l ON l.episode_key = c.episode_key
GROUP BY c.episode_key;

CREATE OR REPLACE VIEW failure_modes AS
SELECT c.episode_key, c.suite, c.task_id, c.init_state_id, c.seed, c.instruction, c.policy,
       c.success_definition, c.episode_length_cap,
       CASE
           WHEN c.errored THEN 'error'
           WHEN COALESCE(v.max_reward, 0) = 4 THEN 'transient_success'
           WHEN COALESCE(v.max_reward, 0) >= 2 AND COALESCE(v.final_reward, 0) < 2 THEN 'dropped'
           WHEN c.task_id = 0 AND COALESCE(v.max_reward, 0) = 0 THEN 'never_touched'
           WHEN c.task_id = 0 AND v.max_reward = 1 THEN 'not_lifted'
           WHEN c.task_id = 0 THEN 'not_transferred'
           WHEN COALESCE(v.max_reward, 0) = 0 THEN 'not_grasped'
           WHEN v.max_reward = 1 THEN 'not_lifted'
           WHEN v.max_reward = 2 THEN 'not_aligned'
           ELSE 'not_inserted'
       END AS failure_mode,
       c.error_kind,
       v.max_reward, v.final_reward, v.first_lift_step, v.first_success_step
FROM scored c
LEFT JOIN aloha_failure_evidence v ON v.episode_key = c.episode_key
WHERE NOT c.scored_success;
