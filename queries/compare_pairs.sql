-- The view `pairs`: one row per episode key present in either of two runs, with the outcome of
-- each under the same success definition and cap. `scored_a` and `scored_b` are the `scored`
-- views (queries/score.sql) of runs A and B. Episodes of one run only are kept (paired = false),
-- so that `compare.sql` counts them instead of dropping them silently.
CREATE OR REPLACE VIEW pairs AS
SELECT COALESCE(a.episode_key, b.episode_key) AS episode_key,
       COALESCE(a.suite, b.suite) AS suite,
       COALESCE(a.task_id, b.task_id) AS task_id,
       COALESCE(a.instruction, b.instruction) AS instruction,
       a.policy AS policy_a,
       b.policy AS policy_b,
       COALESCE(a.success_definition, b.success_definition) AS success_definition,
       a.episode_length_cap AS episode_length_cap_a,
       b.episode_length_cap AS episode_length_cap_b,
       a.scored_success AS success_a,
       b.scored_success AS success_b,
       (a.episode_key IS NOT NULL AND b.episode_key IS NOT NULL) AS paired
FROM scored_a a
FULL OUTER JOIN scored_b b ON a.episode_key = b.episode_key;
