-- Where a run's policy steps spend their time, from the timings stored with every step (tables v5),
-- and what the measured rate means for the canonical protocol. `pipeline bench run` prints it.
--
-- A rollout worker's policy step is: render the cameras (render_ms), call the policy (policy_ms),
-- step the env (sim_ms). An episode's first policy step's render also makes the renderer when its
-- worker has none for the task (uploading the scene's meshes and textures), so the render time is
-- also given for first steps and for the steps after them. For a batched model, policy_ms is the worker's preparation of its query
-- (prepare_ms: image preprocessing), the wait for the forward to start (queue_ms) and the forward
-- (forward_ms, shared by the forward's episodes). The model's busy fraction is the time inside distinct
-- forwards over the span the episodes covered (episodes.started_at .. started_at + wall_s): on a
-- GPU run, an upper bound of the GPU's busy fraction (a forward also holds host work); with model
-- replicas on several GPUs (`devices=`), the sum over the replicas (up to their number).
--
-- The projection takes the canonical protocol at its caps (500 episodes per suite; caps 220, 280,
-- 300, 520 policy steps for libero_spatial, _object, _goal, _10: 660,000 policy steps, what a policy
-- that never succeeds runs) at this run's policy steps per second, on one machine like this one;
-- the 8-replica figure assumes 8 such machines' worth (8x this run's GPUs and cores), i.e. linear
-- scaling: from a one-GPU run, 8 GPUs.
WITH policy_steps AS (
    SELECT * FROM steps WHERE policy_step IS NOT NULL
),
forwards AS (
    SELECT DISTINCT forward_id, forward_ms, forward_batch
    FROM policy_steps WHERE forward_id IS NOT NULL
),
span AS (
    SELECT COUNT(*) AS episodes, MAX(started_at + wall_s) - MIN(started_at) AS span_s
    FROM episodes WHERE started_at IS NOT NULL
),
per_step AS (
    SELECT
        COUNT(*) AS policy_steps,
        AVG(render_ms) AS render_ms,
        AVG(CASE WHEN policy_step = 0 THEN render_ms END) AS first_step_render_ms,
        AVG(CASE WHEN policy_step > 0 THEN render_ms END) AS later_steps_render_ms,
        AVG(sim_ms) AS sim_ms,
        AVG(policy_ms) AS policy_ms,
        AVG(COALESCE(queue_ms, 0)) AS queue_ms,
        AVG(CASE WHEN forward_id IS NULL THEN 0 ELSE COALESCE(prepare_ms, 0) END) AS prepare_ms,
        AVG(CASE WHEN forward_id IS NULL THEN 0 ELSE forward_ms END) AS forward_ms,
        AVG(CASE WHEN forward_id IS NULL THEN 0.0 ELSE 1.0 END) AS queried_fraction
    FROM policy_steps
),
model AS (
    SELECT
        COUNT(*) AS forwards,
        AVG(forward_batch) AS episodes_per_forward,
        MAX(forward_batch) AS max_episodes_per_forward,
        AVG(forward_ms) AS forward_ms_mean,
        SUM(forward_ms) / 1000.0 AS model_busy_s
    FROM forwards
)
SELECT
    span.episodes,
    per_step.policy_steps,
    span.span_s,
    span.episodes * 3600.0 / span.span_s AS episodes_per_hour,
    per_step.policy_steps / span.span_s AS policy_steps_per_s,
    per_step.render_ms,
    per_step.first_step_render_ms,
    per_step.later_steps_render_ms,
    per_step.sim_ms,
    per_step.policy_ms,
    per_step.queue_ms,
    per_step.prepare_ms,
    per_step.forward_ms,
    per_step.policy_ms - per_step.queue_ms - per_step.prepare_ms - per_step.forward_ms AS policy_other_ms,
    per_step.queried_fraction,
    model.forwards,
    model.episodes_per_forward,
    model.max_episodes_per_forward,
    model.forward_ms_mean,
    model.model_busy_s / span.span_s AS model_busy_fraction,
    660000.0 / (per_step.policy_steps / span.span_s) / 3600.0 AS canonical_hours_1_replica,
    660000.0 / (per_step.policy_steps / span.span_s) / 3600.0 / 8.0 AS canonical_hours_8_replicas
FROM span, per_step, model
