-- Which failed episodes get a video (`pipeline videos`, `pipeline report`). Edit freely (run
-- with LIBERO_QUERIES=<dir> to use an edited copy): the command renders whatever rows this
-- returns, one MP4 per row, named {suite}_task{task_id}_init{init_state_id}.mp4 (`_v{variant}` before
-- the extension for a perturbed episode).
--
-- Default, per suite: the first failed episode in (task_id, init_state_id, seed) order (the seed
-- brief's rule), and the first episode of every failure mode. An episode picked for several
-- reasons is rendered once, with its reasons joined.
WITH ranked AS (
    SELECT f.*,
           row_number() OVER (PARTITION BY suite ORDER BY task_id, init_state_id, seed) AS nth_failure,
           row_number() OVER (PARTITION BY suite, failure_mode ORDER BY task_id, init_state_id, seed) AS nth_of_mode
    FROM failure_modes f
),
picked AS (
    SELECT episode_key, 'first failure' AS reason FROM ranked WHERE nth_failure = 1
    UNION ALL
    SELECT episode_key, 'first ' || failure_mode AS reason FROM ranked WHERE nth_of_mode = 1
)
SELECT r.suite, r.task_id, r.init_state_id, r.seed, r.episode_key, r.instruction, r.failure_mode,
       string_agg(DISTINCT p.reason, ', ') AS reasons
FROM picked p
JOIN ranked r ON r.episode_key = p.episode_key
GROUP BY r.suite, r.task_id, r.init_state_id, r.seed, r.episode_key, r.instruction, r.failure_mode
ORDER BY r.suite, r.task_id, r.init_state_id, r.seed
