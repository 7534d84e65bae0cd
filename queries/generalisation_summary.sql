-- LIBERO-Plus in one table: this run's per-category rates (all suites pooled, one row per model)
-- next to the published leaderboard's rows, with the three totals people quote, labelled:
--   total_weighted   pooled successes over all variants run: the README's "Total" (variant
--                    weighted), comparable to it only when every category was run;
--   mean_categories  the plain mean of the categories run (vla-eval's total);
--   robust_avg       the plain mean of the categories run but Language (a third-party "Robust Avg.").
-- `n_errors`: how many of the variants run ended in an error row (counted as failures).
-- Rates rounded to 4 decimals (the leaderboard's have 3). Reads the view `generalisation`
-- (queries/generalisation.sql) and the `published` table.
WITH ours AS (
    SELECT max(success_rate) FILTER (WHERE category = 'Camera') AS camera,
           max(success_rate) FILTER (WHERE category = 'Robot') AS robot,
           max(success_rate) FILTER (WHERE category = 'Language') AS language,
           max(success_rate) FILTER (WHERE category = 'Light') AS light,
           max(success_rate) FILTER (WHERE category = 'Background') AS background,
           max(success_rate) FILTER (WHERE category = 'Noise') AS noise,
           max(success_rate) FILTER (WHERE category = 'Layout') AS layout,
           CAST(sum(n_success) AS DOUBLE) / sum(n_total) AS total_weighted,
           avg(success_rate) AS mean_categories,
           avg(success_rate) FILTER (WHERE category <> 'Language') AS robust_avg,
           sum(n_total) AS n_variants,
           sum(n_errors) AS n_errors,
           count(*) AS n_categories,
           max(suite_base_rate) AS base_rate
    FROM generalisation
    WHERE base_suite = 'all' AND difficulty IS NULL
),
theirs AS (
    SELECT model || CASE WHEN variant IS NULL OR variant = '' THEN '' ELSE ' ' || variant END AS model,
           max(success_rate) FILTER (WHERE perturbation = 'camera') AS camera,
           max(success_rate) FILTER (WHERE perturbation = 'robot') AS robot,
           max(success_rate) FILTER (WHERE perturbation = 'language') AS language,
           max(success_rate) FILTER (WHERE perturbation = 'light') AS light,
           max(success_rate) FILTER (WHERE perturbation = 'background') AS background,
           max(success_rate) FILTER (WHERE perturbation = 'noise') AS noise,
           max(success_rate) FILTER (WHERE perturbation = 'layout') AS layout,
           max(success_rate) FILTER (WHERE perturbation = 'total') AS total_weighted
    FROM published
    WHERE benchmark = 'libero-plus' AND suite IS NULL
    GROUP BY 1
)
SELECT 'this run' AS model, round(camera, 4) AS camera, round(robot, 4) AS robot, round(language, 4) AS language,
       round(light, 4) AS light, round(background, 4) AS background, round(noise, 4) AS noise,
       round(layout, 4) AS layout, round(total_weighted, 4) AS total_weighted,
       round(mean_categories, 4) AS mean_categories, round(robust_avg, 4) AS robust_avg, n_variants, n_errors, n_categories,
       round(base_rate, 4) AS base_rate,
       CASE WHEN n_categories < 7 THEN 'categories not run are null; the totals cover the categories run only, '
                                       || 'so they are not comparable to the leaderboard''s'
            ELSE NULL END AS note
FROM ours
UNION ALL
SELECT model || ' (published)', camera, robot, language, light, background, noise, layout, total_weighted,
       round((camera + robot + language + light + background + noise + layout) / 7, 4),
       round((camera + robot + light + background + noise + layout) / 6, 4),
       NULL, NULL, 7, NULL, 'LIBERO-Plus README leaderboard (10,030 variants, one episode each)'
FROM theirs
ORDER BY CASE WHEN model = 'this run' THEN 0 ELSE 1 END, total_weighted DESC NULLS LAST;
