-- Do two runs' policies compute the same function? Each paired episode's first policy step
-- (policy_step 0) sees the same observation in both runs: the same start state after the same
-- wait steps, rendered alike. So where runs A and B differ only in how the model is computed
-- (quantised weights, another device, a batch instead of one episode per forward), their first
-- actions show how far apart the two computations are; later steps start from states that
-- already differ. `first_actions_a` and `first_actions_b` hold (episode_key, action) at
-- policy_step 0 of each run. One row: episodes paired, episodes whose every dimension is equal,
-- dimensions equal of all compared, the largest |B - A| of a dimension, and its mean.
WITH paired AS (
    SELECT a.episode_key, a.action AS action_a, b.action AS action_b
    FROM first_actions_a a
    JOIN first_actions_b b ON a.episode_key = b.episode_key
),
dims AS (
    SELECT episode_key, unnest(action_a) AS x_a, unnest(action_b) AS x_b
    FROM paired
),
per_episode AS (
    SELECT episode_key,
           count(*) AS dims,
           sum(CASE WHEN x_a = x_b THEN 1 ELSE 0 END) AS dims_equal,
           max(abs(CAST(x_b AS DOUBLE) - CAST(x_a AS DOUBLE))) AS max_abs_diff,
           sum(abs(CAST(x_b AS DOUBLE) - CAST(x_a AS DOUBLE))) AS sum_abs_diff
    FROM dims
    GROUP BY episode_key
)
SELECT count(*) AS n_episodes,
       COALESCE(sum(CASE WHEN dims_equal = dims THEN 1 ELSE 0 END), 0) AS n_episodes_all_equal,
       COALESCE(sum(dims_equal), 0) AS n_dims_equal,
       COALESCE(sum(dims), 0) AS n_dims,
       max(max_abs_diff) AS max_abs_diff,
       sum(sum_abs_diff) / sum(dims) AS mean_abs_diff
FROM per_episode;
