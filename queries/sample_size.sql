-- Trials needed to detect a difference between two independent success rates p0 and p1 = p0 + delta
-- (two-sided test at level alpha with the given power; normal approximation, pooled variance under
-- the null: udfs/src/sample_size.rs), for a comparison on one task and on a suite of {{tasks}}
-- tasks (pooled). Printed by `pipeline sample-size`; parameters substituted and validated there.
-- Runs paired on the same episode keys usually need fewer trials: this is an upper bound for them.
WITH n AS (
    SELECT sample_size_two_proportions({{p0}}, {{p1}}, {{alpha}}, {{power}}) AS per_arm
)
SELECT scope,
       {{p0}} AS p0,
       {{p1}} AS p1,
       {{alpha}} AS alpha,
       {{power}} AS power,
       trials_per_task,
       trials_per_task * n_tasks AS episodes_per_policy
FROM (
    SELECT 'one task' AS scope, 1 AS n_tasks, per_arm AS trials_per_task FROM n
    UNION ALL
    SELECT 'suite of {{tasks}} tasks', {{tasks}}, CAST(ceil(per_arm / CAST({{tasks}} AS DOUBLE)) AS BIGINT) FROM n
) t
ORDER BY n_tasks;
