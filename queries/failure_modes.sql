-- Failure modes: for every episode that failed under the `scored` view's success definition and
-- cap, one primary mode, derived from the stored steps. Defines views; nothing runs until a query
-- reads `failure_modes` (`pipeline failures`, `pipeline report`, or `pipeline sql`).
--
-- Modes, in order of precedence (the first that applies is the primary mode):
--   error              the episode ended early with an error row (sim instability, NaN action,
--                      policy failure): a harness or policy crash, not a behaviour.
--   init_drift         during the wait steps (no motion, gripper open) an object of interest slid
--                      more than drift_m sideways, or was still moving more than settle_m over
--                      the last 3 wait steps: the init state is bad, whatever the policy did.
--                      (Objects settle straight down by up to ~6 cm in the first wait steps of
--                      every LIBERO init state; only sideways and late motion count. A distractor
--                      that tips over during the wait does not explain a failure, so it is not
--                      counted.)
--   saturated_actions  at least saturated_frac of the policy steps had saturated_dims or more of
--                      the 6 arm components at the clip bound (|a| >= saturated_abs, before
--                      clipping): the signature of a wrong un-normalisation key, not a policy.
--   transient_success  the goal held at some policy step within the cap but not at the end (only
--                      under last-step scoring: any-step counts these as successes).
--   dropped            an object of interest was lifted in the gripper (root lift_m above its
--                      start, touching a gripper geom), then lost contact and later came to lie
--                      at least fall_m below its height at the last contact, and its own goal
--                      term (the term whose first argument it is) does not hold at the end. (A
--                      placement lets go about 2 cm above the target; an object let go over a
--                      basket may fall further but lands in its goal.)
--   wrong_object       an object that is not of interest was lifted in the gripper, or was moved
--                      more than moved_m from its start.
--   timeout            no goal progress (never more goal terms true than at the start) and no
--                      grasp of an object of interest (gripper closing while touching it).
--   incomplete         the rest: it grasped an object of interest or made goal progress, but the
--                      goal did not hold by the cap (e.g. a placement that missed, a drawer half
--                      open).
-- The harness faults (error, init_drift, saturated_actions) come first: when one applies, the
-- episode says nothing reliable about the policy.
--
-- "Start" is the pose when the policy takes over: the last wait step (step 0 if there are none).
-- Objects of interest are episodes.objects_of_interest; in runs written before tables v2 (which
-- lack it) an object counts as of interest when the goal's text names it or a region of it.

-- Every threshold of the definitions above, in one place. Edit here (with LIBERO_QUERIES=<dir>
-- pointing at the edited queries folder) to re-derive the modes of a stored run.
CREATE OR REPLACE VIEW failure_thresholds AS
SELECT 0.03  AS lift_m,             -- lifted: root this far above its start, in the gripper
       0.03  AS fall_m,             -- dropped: fell at least this far after contact ended
       0.05  AS moved_m,            -- wrong_object: a non-interest object moved this far
       0.03  AS drift_m,            -- init_drift: sideways slide during the wait steps
       0.01  AS settle_m,           -- init_drift: motion over the last 3 wait steps
       0.999 AS saturated_abs,      -- an action component at the clip bound
       3     AS saturated_dims,     -- a saturated step: this many of the 6 arm components
       0.5   AS saturated_frac;     -- saturated_actions: this share of policy steps saturated

-- One row per (episode, step, object) within the episode's cap, with the evidence per object.
CREATE OR REPLACE VIEW failure_object_steps AS
WITH unnested AS (
    SELECT s.episode_key, s.step, s.policy_step, s.is_wait, s.action, s.gripper_contacts,
           unnest(s.object_poses) AS o
    FROM steps s
    JOIN scored c ON c.episode_key = s.episode_key
    WHERE s.policy_step IS NULL OR s.policy_step < c.episode_length_cap
)
SELECT u.episode_key, u.step, u.policy_step, u.is_wait,
       u.o['name'] AS name,
       u.o['pos'][1] AS x, u.o['pos'][2] AS y, u.o['pos'][3] AS z,
       array_has(u.gripper_contacts, u.o['name']) AS touched,
       u.action[7] > 0 AS closing,
       greatest(e.num_steps_wait - 1, 0) AS start_step,
       e.num_steps_wait - 1 - 3 AS wait_tail_step,
       COALESCE(
           array_has(e.objects_of_interest, u.o['name']),
           regexp_like(array_to_string(e.goal_terms, ' '), '(^| )' || u.o['name'] || '( |_|$)')
       ) AS of_interest
FROM unnested u
JOIN episodes e ON e.episode_key = u.episode_key;

-- Per episode and object: lifted, grasped, fallen, moved, drifted (one pass of window functions).
CREATE OR REPLACE VIEW failure_objects AS
WITH t AS (SELECT * FROM failure_thresholds),
posed AS (
    SELECT f.*,
           max(CASE WHEN f.step = f.start_step THEN f.x END) OVER o AS x0,
           max(CASE WHEN f.step = f.start_step THEN f.y END) OVER o AS y0,
           max(CASE WHEN f.step = f.start_step THEN f.z END) OVER o AS z0,
           lag(f.touched) OVER w AS touched_before,
           lag(f.z) OVER w AS z_before,
           -- a running minimum from the end (cumulative, so linear in the steps)
           min(f.z) OVER (PARTITION BY f.episode_key, f.name ORDER BY f.step DESC
                          ROWS BETWEEN UNBOUNDED PRECEDING AND CURRENT ROW) AS z_lowest_after
    FROM failure_object_steps f
    WINDOW o AS (PARTITION BY f.episode_key, f.name),
           w AS (PARTITION BY f.episode_key, f.name ORDER BY f.step)
),
marked AS (
    SELECT p.*,
           (p.touched AND p.z >= p.z0 + t.lift_m) AS lifted_now,
           max(CASE WHEN p.touched AND p.z >= p.z0 + t.lift_m THEN 1 ELSE 0 END)
               OVER (PARTITION BY p.episode_key, p.name ORDER BY p.step
                     ROWS BETWEEN UNBOUNDED PRECEDING AND 1 PRECEDING) AS lifted_earlier
    FROM t CROSS JOIN posed p  -- the one-row side first: a cross join buffers its left side
)
SELECT episode_key, name, bool_or(of_interest) AS of_interest,
       bool_or(lifted_now AND policy_step IS NOT NULL) AS lifted,
       bool_or(touched AND closing AND policy_step IS NOT NULL) AS grasped,
       -- the gripper lost contact with the lifted object at this step: how far it fell afterwards
       COALESCE(max(CASE WHEN policy_step IS NOT NULL AND touched_before AND NOT touched AND lifted_earlier = 1
                         THEN z_before - z_lowest_after END), 0) AS fall_m,
       max(CASE WHEN policy_step IS NOT NULL
                THEN sqrt(power(x - x0, 2) + power(y - y0, 2) + power(z - z0, 2)) END) AS moved_m,
       COALESCE(max(CASE WHEN is_wait AND step = 0 THEN sqrt(power(x0 - x, 2) + power(y0 - y, 2)) END), 0)
           AS wait_slide_m,
       COALESCE(max(CASE WHEN is_wait AND step = wait_tail_step
                         THEN sqrt(power(x0 - x, 2) + power(y0 - y, 2) + power(z0 - z, 2)) END), 0) AS wait_tail_m
FROM marked
GROUP BY episode_key, name;

-- Per episode and goal term: the object it is about (its first argument) and whether it held at
-- the last policy step within the cap.
CREATE OR REPLACE VIEW failure_term_ends AS
WITH last_step AS (
    SELECT s.episode_key, max(s.policy_step) AS last_step
    FROM steps s JOIN scored c ON c.episode_key = s.episode_key
    WHERE s.policy_step < c.episode_length_cap
    GROUP BY s.episode_key
),
ends AS (
    SELECT s.episode_key, s.goal_terms AS truth, e.goal_terms AS terms
    FROM steps s
    JOIN last_step l ON l.episode_key = s.episode_key AND s.policy_step = l.last_step
    JOIN episodes e ON e.episode_key = s.episode_key
),
indexed AS (
    SELECT episode_key, truth, terms, unnest(range(1, CAST(array_length(terms) AS BIGINT) + 1)) AS i FROM ends
)
SELECT episode_key, split_part(terms[i], ' ', 2) AS name, bool_or(truth[i]) AS holds_at_end
FROM indexed
GROUP BY episode_key, split_part(terms[i], ' ', 2);

-- Per episode: the evidence every mode reads.
CREATE OR REPLACE VIEW failure_evidence AS
WITH t AS (SELECT * FROM failure_thresholds),
per_step AS (
    SELECT s.episode_key, s.policy_step, s.goal,
           COALESCE(array_length(array_remove_all(s.goal_terms, false)), 0) AS terms_true,
           (CASE WHEN abs(s.action[1]) >= t.saturated_abs THEN 1 ELSE 0 END
          + CASE WHEN abs(s.action[2]) >= t.saturated_abs THEN 1 ELSE 0 END
          + CASE WHEN abs(s.action[3]) >= t.saturated_abs THEN 1 ELSE 0 END
          + CASE WHEN abs(s.action[4]) >= t.saturated_abs THEN 1 ELSE 0 END
          + CASE WHEN abs(s.action[5]) >= t.saturated_abs THEN 1 ELSE 0 END
          + CASE WHEN abs(s.action[6]) >= t.saturated_abs THEN 1 ELSE 0 END) >= t.saturated_dims AS saturated,
           s.is_wait, s.step
    FROM t
    CROSS JOIN steps s
    JOIN scored c ON c.episode_key = s.episode_key
    WHERE s.policy_step IS NULL OR s.policy_step < c.episode_length_cap
),
start_terms AS (
    SELECT p.episode_key, first_value(p.terms_true ORDER BY p.step DESC) AS terms_at_start
    FROM per_step p WHERE p.is_wait OR p.step = 0 GROUP BY p.episode_key
),
steps_agg AS (
    SELECT episode_key,
           bool_or(goal) FILTER (WHERE policy_step IS NOT NULL) AS goal_held,
           max(terms_true) FILTER (WHERE policy_step IS NOT NULL) AS max_terms_true,
           avg(CASE WHEN saturated THEN 1.0 ELSE 0.0 END) FILTER (WHERE policy_step IS NOT NULL) AS saturated_share
    FROM per_step GROUP BY episode_key
),
objects AS (
    -- a fall counts against an object of interest whose own goal term does not hold at the end
    SELECT o.*, (o.of_interest AND o.lifted AND NOT COALESCE(te.holds_at_end, false)) AS fell_from_goal
    FROM failure_objects o
    LEFT JOIN failure_term_ends te ON te.episode_key = o.episode_key AND te.name = o.name
),
objects_agg AS (
    SELECT episode_key,
           max(CASE WHEN fell_from_goal THEN fall_m ELSE 0 END) AS interest_fall_m,
           bool_or(of_interest AND grasped) AS interest_grasped,
           bool_or(NOT of_interest AND lifted) AS other_lifted,
           max(CASE WHEN NOT of_interest THEN moved_m ELSE 0 END) AS other_moved_m,
           max(CASE WHEN of_interest THEN wait_slide_m ELSE 0 END) AS wait_slide_m,
           max(CASE WHEN of_interest THEN wait_tail_m ELSE 0 END) AS wait_tail_m,
           -- the object behind the largest of each, for the reader
           first_value(name ORDER BY CASE WHEN fell_from_goal THEN fall_m ELSE 0 END DESC) AS fallen_object,
           first_value(name ORDER BY CASE WHEN NOT of_interest THEN moved_m ELSE 0 END DESC) AS moved_object,
           first_value(name ORDER BY CASE WHEN of_interest THEN greatest(wait_slide_m, wait_tail_m) ELSE 0 END DESC)
               AS drifted_object
    FROM objects GROUP BY episode_key
)
SELECT a.episode_key,
       COALESCE(a.goal_held, false) AS goal_held,
       COALESCE(a.max_terms_true, 0) > COALESCE(st.terms_at_start, 0) AS goal_progress,
       COALESCE(a.saturated_share, 0) AS saturated_share,
       COALESCE(o.interest_fall_m, 0) AS interest_fall_m,
       o.fallen_object,
       COALESCE(o.interest_grasped, false) AS interest_grasped,
       COALESCE(o.other_lifted, false) AS other_lifted,
       COALESCE(o.other_moved_m, 0) AS other_moved_m,
       o.moved_object,
       COALESCE(o.wait_slide_m, 0) AS wait_slide_m,
       COALESCE(o.wait_tail_m, 0) AS wait_tail_m,
       o.drifted_object
FROM steps_agg a
LEFT JOIN start_terms st ON st.episode_key = a.episode_key
LEFT JOIN objects_agg o ON o.episode_key = a.episode_key;

-- One row per failed episode: its primary mode and the evidence behind it.
CREATE OR REPLACE VIEW failure_modes AS
WITH t AS (SELECT * FROM failure_thresholds)
SELECT c.episode_key, c.suite, c.task_id, c.init_state_id, c.seed, c.instruction, c.policy,
       c.success_definition, c.episode_length_cap,
       CASE
           WHEN c.errored THEN 'error'
           WHEN COALESCE(v.wait_slide_m, 0) > t.drift_m OR COALESCE(v.wait_tail_m, 0) > t.settle_m THEN 'init_drift'
           WHEN COALESCE(v.saturated_share, 0) >= t.saturated_frac THEN 'saturated_actions'
           WHEN COALESCE(v.goal_held, false) THEN 'transient_success'
           WHEN COALESCE(v.interest_fall_m, 0) >= t.fall_m THEN 'dropped'
           WHEN COALESCE(v.other_lifted, false) OR COALESCE(v.other_moved_m, 0) > t.moved_m THEN 'wrong_object'
           WHEN NOT COALESCE(v.goal_progress, false) AND NOT COALESCE(v.interest_grasped, false) THEN 'timeout'
           ELSE 'incomplete'
       END AS failure_mode,
       c.error_kind,
       v.goal_progress, v.interest_grasped, v.interest_fall_m, v.fallen_object,
       v.other_lifted, v.other_moved_m, v.moved_object,
       v.wait_slide_m, v.wait_tail_m, v.drifted_object, v.saturated_share
FROM t
CROSS JOIN scored c
LEFT JOIN failure_evidence v ON v.episode_key = c.episode_key
WHERE NOT c.scored_success;
