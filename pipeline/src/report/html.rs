//! The report page: query rows laid out as HTML tables and inline SVG plots.

use super::RunTables;
use anyhow::Result;
use arrow::record_batch::RecordBatch;
use arrow::util::display::array_value_to_string;
use base64::Engine;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

/// Query rows by column name, every value as its display string ("" for null).
struct Rows {
    rows: Vec<BTreeMap<String, String>>,
}

impl Rows {
    fn of(batches: &[RecordBatch]) -> Rows {
        let mut rows = vec![];
        for b in batches {
            for r in 0..b.num_rows() {
                let row = b
                    .schema()
                    .fields()
                    .iter()
                    .zip(b.columns())
                    .map(|(f, c)| {
                        let v =
                            if c.is_null(r) { String::new() } else { array_value_to_string(c, r).unwrap_or_default() };
                        (f.name().clone(), v)
                    })
                    .collect();
                rows.push(row);
            }
        }
        Rows { rows }
    }
}

fn get<'a>(row: &'a BTreeMap<String, String>, col: &str) -> &'a str {
    row.get(col).map(String::as_str).unwrap_or("")
}

fn num(row: &BTreeMap<String, String>, col: &str) -> f64 {
    get(row, col).parse().unwrap_or(f64::NAN)
}

/// HTML-escape text.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn pct(x: f64) -> String {
    if x.is_finite() { format!("{:.1}%", 100.0 * x) } else { "-".into() }
}

/// The page and the warnings it shows at the top (also printed by the command).
pub struct Page {
    pub html: String,
    pub warnings: Vec<String>,
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1200px;color:#222}\
h1{margin-bottom:4px}h2{border-bottom:2px solid #ddd;padding-bottom:4px;margin-top:36px}\
table{border-collapse:collapse;margin:8px 0;font-size:13px}td,th{border:1px solid #ccc;padding:3px 7px;text-align:left}\
th{background:#f3f3f3}td.n{text-align:right;font-variant-numeric:tabular-nums}\
.warn{background:#fff3cd;border:1px solid #e0b000;padding:8px 12px;margin:6px 0}\
.diff{color:#a33}.muted{color:#777}.cell{width:54px;text-align:center;font-size:12px}\
figure{display:inline-block;margin:6px}figcaption{font-size:12px;max-width:520px}\
video,img{max-width:520px;border:1px solid #ccc}";

/// Fixed palette of LIBERO's failure modes (harness faults in greys and purple).
const MODE_COLORS: &[(&str, &str)] = &[
    ("timeout", "#9ecae1"),
    ("incomplete", "#3182bd"),
    ("wrong_object", "#fd8d3c"),
    ("dropped", "#e6550d"),
    ("transient_success", "#74c476"),
    ("saturated_actions", "#756bb1"),
    ("init_drift", "#969696"),
    ("error", "#252525"),
];

/// ALOHA-sim's modes (`queries/aloha_failure_modes.sql`): the reward stage an episode stopped at,
/// light (nothing touched) to dark (all but done), then the modes it shares with LIBERO.
const ALOHA_MODE_COLORS: &[(&str, &str)] = &[
    ("never_touched", "#c6dbef"),
    ("not_grasped", "#9ecae1"),
    ("not_lifted", "#6baed6"),
    ("not_transferred", "#3182bd"),
    ("not_aligned", "#fdae6b"),
    ("not_inserted", "#fd8d3c"),
    ("dropped", "#e6550d"),
    ("transient_success", "#74c476"),
    ("error", "#252525"),
];

fn mode_color(mode: &str) -> &'static str {
    MODE_COLORS.iter().chain(ALOHA_MODE_COLORS).find(|(m, _)| *m == mode).map_or("#bbbbbb", |(_, c)| c)
}

/// The benchmarks of the runs, as the page names them ("LIBERO", "ALOHA-sim", or both).
fn benchmarks_of(runs: &[RunTables]) -> String {
    let mut names: Vec<&str> = runs
        .iter()
        .map(|r| match r.manifest.env {
            libero_schema::Benchmark::Libero => "LIBERO",
            libero_schema::Benchmark::AlohaSim => "ALOHA-sim",
        })
        .collect();
    names.dedup();
    names.sort();
    names.dedup();
    names.join(" + ")
}

impl Page {
    pub fn build(runs: &[RunTables], scoring: &str, out: &Path, embed_limit: u64) -> Result<Page> {
        let mut warnings = vec![];
        let mut body = String::new();
        let subject = &runs[0];
        let _ = write!(
            body,
            "<h1>{} evaluation: {}</h1><p class=muted>success definition: <b>{}</b> · runs: {} · every number below is a query over the stored steps (queries/*.sql)</p>",
            benchmarks_of(runs),
            esc(&subject.manifest.policy),
            esc(scoring),
            runs.iter()
                .map(|r| format!("<code>{}</code> ({})", esc(&r.location), esc(&r.manifest.policy)))
                .collect::<Vec<_>>()
                .join(", ")
        );

        // Warnings derived from the rows: baselines that succeed, harness faults, protocol.
        for r in runs {
            let suites = Rows::of(&r.suites);
            let baseline = matches!(r.manifest.policy.as_str(), "random" | "lift");
            for s in &suites.rows {
                let rate = num(s, "success_rate");
                if baseline && rate > crate::results::BASELINE_MAX_SUCCESS {
                    warnings.push(format!(
                        "baseline `{}` scored {} on {}: a baseline must fail; the success check, the protocol or the bundles are broken",
                        r.manifest.policy,
                        pct(rate),
                        get(s, "suite")
                    ));
                }
                if get(s, "n_rollouts_per_task") != "50" {
                    warnings.push(format!(
                        "{} on {}: {} trials per task, not the canonical 50: intervals are wide and published numbers are not comparable",
                        r.manifest.policy,
                        get(s, "suite"),
                        get(s, "n_rollouts_per_task")
                    ));
                }
            }
            for f in &Rows::of(&r.failure_summary).rows {
                if get(f, "harness_fault") == "true" {
                    warnings.push(format!(
                        "{} on {}: {} episode(s) failed by a harness fault ({}), not by the policy",
                        r.manifest.policy,
                        get(f, "suite"),
                        get(f, "n"),
                        get(f, "failure_mode")
                    ));
                }
            }
        }
        body.push_str("<div id=warnings>");
        for w in &warnings {
            let _ = write!(body, "<div class=warn>{}</div>", esc(w));
        }
        body.push_str("</div>");

        section_results(&mut body, runs);
        section_heatmap(&mut body, runs);
        section_failures(&mut body, runs);
        section_videos(&mut body, subject, out, embed_limit);
        section_smoke(&mut body, subject, out);
        section_robustness(&mut body, runs);
        section_generalisation(&mut body, runs);
        section_pro_robustness_cases(&mut body, runs);
        section_published(&mut body, runs);
        section_provenance(&mut body, runs);

        let html = format!(
            "<!doctype html><html lang=en><head><meta charset=utf-8><title>{} report: {}</title><style>{STYLE}</style></head><body>{body}<script>{SCRIPT}</script></body></html>",
            benchmarks_of(runs),
            esc(&subject.manifest.policy)
        );
        Ok(Page { html, warnings })
    }
}

/// The page's one script: hide comparison rows whose protocol differs, on request. It marks the
/// body when it has run, which the headless-browser test reads.
const SCRIPT: &str = "(function(){var box=document.getElementById('same-protocol');\
var rows=document.querySelectorAll('#published tbody tr');\
function apply(){rows.forEach(function(r){r.style.display=(box.checked&&r.dataset.differs==='1')?'none':'';});}\
if(box){box.addEventListener('change',apply);apply();}\
document.body.dataset.ready='1';})();";

fn section_results(body: &mut String, runs: &[RunTables]) {
    body.push_str("<h2 id=results>Success per suite (Wilson 95% intervals)</h2>");
    let rows: Vec<_> = runs.iter().flat_map(|r| Rows::of(&r.suites).rows).collect();
    // Plot: one row per (suite, policy), a bar for the rate and a whisker for the interval.
    let (w, row_h, left) = (760.0, 22.0, 260.0);
    let h = row_h * rows.len() as f64 + 30.0;
    let _ = write!(body, "<svg id=success-plot width={w} height={h} role=img aria-label='success per suite'>");
    for t in 0..=10 {
        let x = left + (w - left - 20.0) * t as f64 / 10.0;
        let _ = write!(
            body,
            "<line x1={x} y1=0 x2={x} y2={} stroke=#eee /><text x={x} y={} font-size=10 text-anchor=middle>{}%</text>",
            h - 20.0,
            h - 6.0,
            t * 10
        );
    }
    for (i, r) in rows.iter().enumerate() {
        let y = i as f64 * row_h + 4.0;
        let scale = |x: f64| left + (w - left - 20.0) * x.clamp(0.0, 1.0);
        let (rate, lo, hi) = (num(r, "success_rate"), num(r, "ci_lo"), num(r, "ci_hi"));
        let _ = write!(
            body,
            "<text x=4 y={} font-size=12>{} · {}</text><rect x={left} y={y} width={} height={} fill=#6baed6><title>{} [{}, {}]</title></rect>\
             <line x1={} y1={} x2={} y2={} stroke=#222 stroke-width=2 /><line x1={} y1={y} x2={} y2={} stroke=#222 /><line x1={} y1={y} x2={} y2={} stroke=#222 />",
            y + 13.0,
            esc(get(r, "suite")),
            esc(get(r, "policy")),
            (scale(rate) - left).max(0.0),
            row_h - 6.0,
            pct(rate),
            pct(lo),
            pct(hi),
            scale(lo),
            y + (row_h - 6.0) / 2.0,
            scale(hi),
            y + (row_h - 6.0) / 2.0,
            scale(lo),
            scale(lo),
            y + row_h - 6.0,
            scale(hi),
            scale(hi),
            y + row_h - 6.0,
        );
    }
    body.push_str("</svg>");
    table(
        body,
        "results-table",
        &rows,
        &[
            ("suite", "suite"),
            ("policy", "policy"),
            ("n_success", "successes"),
            ("n_total", "episodes"),
            ("success_rate", "rate"),
            ("ci_lo", "95% lo"),
            ("ci_hi", "95% hi"),
            ("n_error", "errors"),
            ("episode_length_cap", "cap"),
            ("n_rollouts_per_task", "trials/task"),
            ("success_definition", "success"),
        ],
    );
}

fn section_heatmap(body: &mut String, runs: &[RunTables]) {
    body.push_str(
        "<h2 id=tasks>Success per task</h2><p class=muted>k/n per task; hover for the instruction and interval.</p>",
    );
    for r in runs {
        let rows = Rows::of(&r.tasks).rows;
        let mut suites: BTreeMap<&str, Vec<&BTreeMap<String, String>>> = BTreeMap::new();
        for t in &rows {
            suites.entry(get(t, "suite")).or_default().push(t);
        }
        // a LIBERO suite has 10 tasks, ALOHA-sim 2: as many columns as the run's largest task id
        // needs, at most 10
        let columns =
            rows.iter().filter_map(|t| get(t, "task_id").parse::<usize>().ok()).max().map_or(1, |m| (m + 1).min(10));
        let _ = write!(body, "<table class=heatmap><tr><th>{}</th>", esc(&r.manifest.policy));
        for t in 0..columns {
            let _ = write!(body, "<th class=cell>task {t}</th>");
        }
        body.push_str("</tr>");
        for (suite, tasks) in &suites {
            let _ = write!(body, "<tr><th>{}</th>", esc(suite));
            for t in 0..columns {
                match tasks.iter().find(|x| get(x, "task_id") == t.to_string()) {
                    Some(x) => {
                        let rate = num(x, "success_rate");
                        let title = format!(
                            "{} · {} [{}, {}]",
                            esc(get(x, "instruction")),
                            pct(rate),
                            pct(num(x, "ci_lo")),
                            pct(num(x, "ci_hi"))
                        );
                        rate_cell(body, x, &title);
                    }
                    None => body.push_str("<td class=cell>-</td>"),
                }
            }
            body.push_str("</tr>");
        }
        body.push_str("</table>");
    }
}

/// A heat-map cell: k/n of the row, shaded white (0%) to green (100%) by its `success_rate`,
/// `title` on hover.
/// A heat-map cell: k/n on a colour of the rate; a row with error episodes (`n_errors`, counted
/// as failures in k/n) says how many under it.
fn rate_cell(body: &mut String, row: &BTreeMap<String, String>, title: &str) {
    let rate = num(row, "success_rate");
    let g = (255.0 - 120.0 * rate) as u8;
    let rb = (255.0 - 200.0 * rate) as u8;
    let errors = match get(row, "n_errors") {
        "" | "0" => String::new(),
        e => format!("<br><small class=errors>{} error{}</small>", esc(e), if e == "1" { "" } else { "s" }),
    };
    let _ = write!(
        body,
        "<td class=cell style='background:rgb({rb},{g},{rb})' title='{title}'>{}/{}{errors}</td>",
        get(row, "n_success"),
        get(row, "n_total")
    );
}

fn section_failures(body: &mut String, runs: &[RunTables]) {
    body.push_str(
        "<h2 id=failures>Failure modes</h2><p class=muted>One primary mode per failed episode (queries/failure_modes.sql, \
         which defines each mode and holds the thresholds; ALOHA-sim's are the reward stage an episode stopped at, queries/aloha_failure_modes.sql). \
         Harness faults (error, init_drift, saturated_actions) are the set-up's, not the policy's.</p>",
    );
    let rows: Vec<_> = runs.iter().flat_map(|r| Rows::of(&r.failure_summary).rows).collect();
    if rows.is_empty() {
        body.push_str("<p>No failed episode under this success definition.</p>");
        return;
    }
    let mut groups: BTreeMap<(String, String), Vec<&BTreeMap<String, String>>> = BTreeMap::new();
    for r in &rows {
        groups.entry((get(r, "suite").to_string(), get(r, "policy").to_string())).or_default().push(r);
    }
    let (w, row_h, left) = (760.0, 22.0, 260.0);
    let h = row_h * groups.len() as f64 + 4.0;
    body.push_str("<div class=legend>");
    let has = |b: libero_schema::Benchmark| runs.iter().any(|r| r.manifest.env == b);
    let mut legend: Vec<&(&str, &str)> = vec![];
    if has(libero_schema::Benchmark::Libero) {
        legend.extend(MODE_COLORS);
    }
    if has(libero_schema::Benchmark::AlohaSim) {
        legend.extend(ALOHA_MODE_COLORS.iter().filter(|m| !legend.contains(m)).collect::<Vec<_>>());
    }
    for (m, c) in legend {
        let _ = write!(
            body,
            "<span style='display:inline-block;width:10px;height:10px;background:{c}'></span> {m} &nbsp; "
        );
    }
    body.push_str("</div>");
    let _ = write!(body, "<svg id=failure-plot width={w} height={h} role=img aria-label='failure modes'>");
    for (i, ((suite, policy), modes)) in groups.iter().enumerate() {
        let y = i as f64 * row_h + 4.0;
        let _ = write!(body, "<text x=4 y={} font-size=12>{} · {}</text>", y + 13.0, esc(suite), esc(policy));
        let mut x = left;
        for m in modes {
            // share of the suite's episodes, so the bar's length is the failure rate
            let width = (w - left - 20.0) * num(m, "share_of_episodes");
            let _ = write!(
                body,
                "<rect x={x} y={y} width={width} height={} fill={}><title>{}: {} of {} episodes</title></rect>",
                row_h - 6.0,
                mode_color(get(m, "failure_mode")),
                esc(get(m, "failure_mode")),
                get(m, "n"),
                get(m, "n_episodes")
            );
            x += width;
        }
    }
    body.push_str("</svg>");
    table(
        body,
        "failure-table",
        &rows,
        &[
            ("suite", "suite"),
            ("policy", "policy"),
            ("failure_mode", "mode"),
            ("harness_fault", "harness fault"),
            ("n", "episodes"),
            ("n_failed", "of failed"),
            ("share_of_failures", "share of failures"),
            ("share_of_episodes", "share of episodes"),
        ],
    );
}

fn section_videos(body: &mut String, subject: &RunTables, out: &Path, embed_limit: u64) {
    body.push_str(
        "<h2 id=videos>Selected failure videos</h2><p class=muted>Chosen by queries/video_selection.sql (per suite: the first failure and one per failure mode), \
         rendered by replay with <code>pipeline videos</code>.</p>",
    );
    let selection = Rows::of(&subject.selection).rows;
    if selection.is_empty() {
        body.push_str("<p>No failed episode: nothing to show.</p>");
        return;
    }
    let dir = out.join("failures");
    let mut embedded = 0u64;
    let mut missing = 0;
    for s in &selection {
        let file = crate::video::video_file_name(
            get(s, "suite"),
            get(s, "task_id"),
            get(s, "init_state_id"),
            get(s, "episode_key"),
        );
        let caption = format!(
            "<figcaption><b>{}</b> · {} · {}<br>{}</figcaption>",
            esc(get(s, "episode_key")),
            esc(get(s, "failure_mode")),
            esc(get(s, "reasons")),
            esc(get(s, "instruction"))
        );
        // A video counts only if `pipeline videos` made it from this run (selection.csv says so).
        let made_here = video_of_run(&dir, &file, &subject.manifest.run_config);
        match made_here.then(|| std::fs::read(dir.join(&file)).ok()).flatten() {
            Some(bytes) if embedded + bytes.len() as u64 <= embed_limit => {
                embedded += bytes.len() as u64;
                let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
                let _ = write!(
                    body,
                    "<figure><video controls muted src='data:video/mp4;base64,{data}'></video>{caption}</figure>"
                );
            }
            Some(_) => {
                let _ = write!(
                    body,
                    "<figure><video controls muted src='failures/{}'></video>{caption}</figure>",
                    esc(&file)
                );
            }
            None => {
                missing += 1;
                let _ = write!(body, "<figure><div class=muted>no video yet: {}</div>{caption}</figure>", esc(&file));
            }
        }
    }
    if missing > 0 {
        let _ = write!(
            body,
            "<p class=warn>{missing} selected video(s) not rendered from this run: run <code>pipeline videos --run {}</code> (or <code>pipeline report --videos</code>).</p>",
            esc(&subject.location)
        );
    }
}

/// `failures/videos.json` (written by `pipeline videos`) lists `file` as made from this run.
fn video_of_run(dir: &Path, file: &str, run_config: &str) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join("videos.json")) else { return false };
    let Ok(index) = serde_json::from_str::<serde_json::Value>(&text) else { return false };
    index["run_config"] == run_config && index["videos"].as_array().is_some_and(|v| v.iter().any(|f| f == file))
}

fn section_smoke(body: &mut String, subject: &RunTables, out: &Path) {
    // `pipeline smoke` draws LIBERO's suites; an ALOHA-sim run's pictures are its failure videos
    if subject.manifest.env != libero_schema::Benchmark::Libero {
        return;
    }
    body.push_str("<h2 id=smoke>Smoke pictures</h2><p class=muted>Task 0, init state 0 of each suite as the policy sees it (agentview | eye-in-hand), from <code>pipeline smoke</code>.</p>");
    let suites: Vec<String> = Rows::of(&subject.suites).rows.iter().map(|r| get(r, "suite").to_string()).collect();
    let mut shown = 0;
    for suite in &suites {
        if let Ok(bytes) = std::fs::read(out.join("smoke").join(format!("{suite}.png"))) {
            let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
            let _ = write!(
                body,
                "<figure><img alt='{0}' src='data:image/png;base64,{data}'><figcaption>{0}</figcaption></figure>",
                esc(suite)
            );
            shown += 1;
        }
    }
    if shown == 0 {
        body.push_str(
            "<p class=warn>No smoke pictures in this output folder: run <code>pipeline smoke</code> first.</p>",
        );
    }
}

/// LIBERO-PRO beside the base suites: the brief's question (which suite generalises, which is
/// memorised) in one table per run, then every cell with its interval.
fn section_robustness(body: &mut String, runs: &[RunTables]) {
    if runs.iter().all(|r| r.robustness.is_empty()) {
        return;
    }
    body.push_str(
        "<h2 id=robustness>Is the number real? LIBERO-PRO beside the base suites</h2><p class=muted>\
         queries/robustness.sql and robustness_summary.sql. Per base suite its rate and each perturbation's; \
         the mean drop over the perturbations run, the worst, and the rank of the suite that falls most. \
         <code>lan</code> is compared pair by pair (same scene and init state as the base), the others \
         unpaired; the LIBERO-PRO total is the plain mean of the suite × perturbation cells, as the \
         authors compute theirs.</p>",
    );
    for r in runs.iter().filter(|r| !r.robustness.is_empty()) {
        let _ = write!(body, "<h3>{} <span class=muted>({})</span></h3>", esc(&r.manifest.policy), esc(&r.location));
        let summary = Rows::of(&r.robustness_summary).rows;
        table(
            body,
            "robustness-summary",
            &summary,
            &[
                ("base_suite", "suite"),
                ("base", "base"),
                ("swap", "swap (position)"),
                ("object", "object"),
                ("lan", "lan (semantic)"),
                ("task", "task"),
                ("env", "env"),
                ("mean_drop", "mean drop"),
                ("worst_perturbation", "worst"),
                ("falls_most_rank", "falls most (rank)"),
                ("libero_pro_total", "LIBERO-PRO total"),
                ("n_cells", "cells"),
                ("note", "note"),
            ],
        );
        table(
            body,
            "robustness",
            &Rows::of(&r.robustness).rows,
            &[
                ("base_suite", "suite"),
                ("perturbation", "perturbation"),
                ("n_total", "n"),
                ("success_rate", "rate"),
                ("ci_lo", "ci_lo"),
                ("ci_hi", "ci_hi"),
                ("base_rate", "base rate (same tasks)"),
                ("drop_from_base", "drop"),
                ("drop_ci_lo", "drop 95% lo"),
                ("drop_ci_hi", "drop 95% hi"),
                ("paired", "paired"),
                ("instruction_changed", "instruction changed"),
                ("published", "LIBERO-PRO leaderboard"),
            ],
        );
    }
}

/// LIBERO-PRO's robustness cases: per suite × case the rate and its paired drop from the base rows.
fn section_pro_robustness_cases(body: &mut String, runs: &[RunTables]) {
    if runs.iter().all(|r| r.pro_robustness_cases.is_empty()) {
        return;
    }
    body.push_str(
        "<h2 id=pro-robustness-cases>Does the number survive perturbation? LIBERO-PRO's robustness cases</h2>\
         <p class=muted>queries/pro_robustness_cases.sql. Per suite and case: the success rate (Wilson 95%) and the \
         drop from the base rate, paired with each episode's unperturbed twin (same task, init state and seed) when \
         the run has them (Newcombe's paired interval, McNemar's exact p). Error episodes count as failures. The \
         cases' objects are chosen by this tool's rules (README), not the authors' generator.</p>",
    );
    for r in runs.iter().filter(|r| !r.pro_robustness_cases.is_empty()) {
        let _ = write!(body, "<h3>{} <span class=muted>({})</span></h3>", esc(&r.manifest.policy), esc(&r.location));
        table(
            body,
            "pro-robustness-cases",
            &Rows::of(&r.pro_robustness_cases).rows,
            &[
                ("base_suite", "suite"),
                ("robustness_case", "case"),
                ("n_total", "episodes"),
                ("n_errors", "error episodes"),
                ("success_rate", "success rate"),
                ("ci_lo", "95% lo"),
                ("ci_hi", "95% hi"),
                ("base_rate", "base rate"),
                ("drop_from_base", "drop"),
                ("drop_lo", "drop 95% lo"),
                ("drop_hi", "drop 95% hi"),
                ("mcnemar_p", "McNemar p"),
                ("paired", "paired"),
            ],
        );
    }
}

/// LIBERO-Plus by category: a heat map of suite (and difficulty, when labelled) × category, each
/// cell its rate with interval and drop on hover, then this run beside the leaderboard.
fn section_generalisation(body: &mut String, runs: &[RunTables]) {
    if runs.iter().all(|r| r.generalisation.is_empty()) {
        return;
    }
    body.push_str(
        "<h2 id=generalisation>Does the number survive perturbation? LIBERO-Plus by category</h2><p class=muted>\
         queries/generalisation.sql and generalisation_summary.sql. Each cell: success rate over the variants of \
         the category (k/n; episodes that ended in an error row count as failures, and their number is shown \
         under it); on hover its drop from the base rate with both 95% intervals, paired with each \
         variant's twin (its base task from the same init state, unperturbed) when the run has them. The base \
         column is all of the suite's base rows. Rows: the suites, then all suites pooled, then per difficulty level \
         when the spec carries the authors' labels. Light, Background and Layout need assets or bundles not \
         available here; the totals cover the categories run.</p>",
    );
    const CATEGORIES: [&str; 7] = ["Camera", "Robot", "Language", "Light", "Background", "Noise", "Layout"];
    for r in runs.iter().filter(|r| !r.generalisation.is_empty()) {
        let _ = write!(body, "<h3>{} <span class=muted>({})</span></h3>", esc(&r.manifest.policy), esc(&r.location));
        let rows = Rows::of(&r.generalisation).rows;
        let mut lines: Vec<(String, Vec<&BTreeMap<String, String>>)> = Vec::new();
        for row in &rows {
            let label = match get(row, "difficulty") {
                "" => get(row, "base_suite").to_string(),
                d => format!("difficulty {d}"),
            };
            match lines.iter_mut().find(|(l, _)| *l == label) {
                Some((_, cells)) => cells.push(row),
                None => lines.push((label, vec![row])),
            }
        }
        body.push_str("<table class=heatmap id=generalisation-map><tr><th></th><th>base</th>");
        for c in CATEGORIES {
            let _ = write!(body, "<th class=cell>{c}</th>");
        }
        body.push_str("</tr>");
        for (label, cells) in &lines {
            let base = cells.first().map(|c| get(c, "suite_base_rate")).unwrap_or("");
            let base = if base.is_empty() { "-".to_string() } else { pct(base.parse().unwrap_or(f64::NAN)) };
            let base = match cells.first().map(|c| get(c, "suite_base_n_errors")) {
                None | Some("" | "0") => base,
                Some(e) => {
                    format!("{base}<br><small class=errors>{} error{}</small>", esc(e), if e == "1" { "" } else { "s" })
                }
            };
            let _ = write!(body, "<tr><th>{}</th><td class=n>{base}</td>", esc(label));
            for c in CATEGORIES {
                match cells.iter().find(|x| get(x, "category") == c) {
                    Some(x) => {
                        let rate = num(x, "success_rate");
                        let title = format!(
                            "{c}: {} [{}, {}], {} of {} episodes errors (failures); drop from {} base {} [{}, {}], \
                             {} of its {} episodes errors",
                            pct(rate),
                            pct(num(x, "ci_lo")),
                            pct(num(x, "ci_hi")),
                            get(x, "n_errors"),
                            get(x, "n_total"),
                            if get(x, "paired") == "true" { "its twins'" } else { "the suite's" },
                            pct(num(x, "drop_from_base")),
                            pct(num(x, "drop_lo")),
                            pct(num(x, "drop_hi")),
                            get(x, "base_n_errors"),
                            get(x, "base_n")
                        );
                        rate_cell(body, x, &title);
                    }
                    None => body.push_str("<td class=cell>-</td>"),
                }
            }
            body.push_str("</tr>");
        }
        body.push_str("</table>");
        table(
            body,
            "generalisation-summary",
            &Rows::of(&r.generalisation_summary).rows,
            &[
                ("model", "model"),
                ("camera", "Camera"),
                ("robot", "Robot"),
                ("language", "Language"),
                ("light", "Light"),
                ("background", "Background"),
                ("noise", "Noise"),
                ("layout", "Layout"),
                ("total_weighted", "total (variant-weighted)"),
                ("mean_categories", "mean of categories"),
                ("robust_avg", "mean without Language"),
                ("n_variants", "variants"),
                ("n_errors", "error episodes"),
            ],
        );
        let summary = Rows::of(&r.generalisation_summary).rows;
        if let Some(note) = summary.iter().find(|x| get(x, "model") == "this run").map(|x| get(x, "note")) {
            let _ = write!(body, "<p class=muted>{}</p>", esc(note));
        }
    }
}

fn section_published(body: &mut String, runs: &[RunTables]) {
    body.push_str(
        "<h2 id=comparison>Beside the published numbers</h2><p class=muted>data/published_libero.csv (queries/published_comparison.sql). \
         A published number measured under another protocol is not the same quantity: the differences are named in red.</p>\
         <label><input type=checkbox id=same-protocol> only rows with no protocol difference</label>",
    );
    let rows: Vec<_> = runs.iter().flat_map(|r| Rows::of(&r.published).rows).collect();
    body.push_str("<table id=published><thead><tr><th>suite</th><th>this run</th><th>rate [95%]</th><th>published model</th><th>variant</th><th>reported by</th><th>published</th><th>in our interval</th><th>protocol differences</th></tr></thead><tbody>");
    for r in &rows {
        let diff = get(r, "protocol_differences");
        let _ = write!(
            body,
            "<tr data-differs='{}'><td>{}</td><td>{}</td><td class=n>{} [{}, {}]</td><td>{}</td><td>{}</td><td>{}</td><td class=n>{}</td><td>{}</td><td class=diff>{}</td></tr>",
            u8::from(!diff.is_empty()),
            esc(get(r, "suite")),
            esc(get(r, "policy")),
            pct(num(r, "success_rate")),
            pct(num(r, "ci_lo")),
            pct(num(r, "ci_hi")),
            esc(get(r, "published_model")),
            esc(get(r, "published_variant")),
            esc(get(r, "reported_by")),
            pct(num(r, "published_rate")),
            if get(r, "published_rate_in_ci") == "true" { "yes" } else { "no" },
            esc(diff)
        );
    }
    body.push_str("</tbody></table>");
    if rows.is_empty() {
        body.push_str(
            "<p class=muted>No published number for the suites of these runs in data/published_libero.csv \
             (ALOHA-sim's published rates are per task and per training set: see the README's ALOHA-sim section).</p>",
        );
    }
}

fn section_provenance(body: &mut String, runs: &[RunTables]) {
    body.push_str("<h2 id=provenance>Provenance</h2>");
    for r in runs {
        let m = &r.manifest;
        let _ = write!(body, "<h3>{}</h3><table>", esc(&r.location));
        let items: Vec<(&str, String)> = vec![
            ("policy", m.policy.clone()),
            ("policy identity", m.policy_identity.to_string()),
            ("episode caps (policy steps)", serde_json::to_string(&m.max_steps).unwrap_or_default()),
            ("wait steps", m.num_steps_wait.to_string()),
            ("stop on success", m.stop_on_success.to_string()),
            ("MuJoCo", m.mujoco_version.clone()),
            ("bundles (sha256)", m.bundles_hash.clone()),
            ("bundle format", m.bundle_format_version.to_string()),
            ("tables version", m.tables_version.to_string()),
            ("control", format!("{} Hz, {} substeps per step", m.control_freq_hz, m.substeps_per_step)),
            ("pipeline", format!("{} (git {})", m.pipeline_version, m.git_revision)),
            ("run config", m.run_config.clone()),
            ("created", m.created_at.clone()),
        ];
        for (k, v) in items {
            let _ = write!(body, "<tr><th>{}</th><td><code>{}</code></td></tr>", esc(k), esc(&v));
        }
        body.push_str("</table>");
    }
}

/// A plain table of `columns` (key, heading); numbers right-aligned, rates as percentages.
fn table(body: &mut String, id: &str, rows: &[BTreeMap<String, String>], columns: &[(&str, &str)]) {
    let _ = write!(body, "<table id={id}><thead><tr>");
    for (_, h) in columns {
        let _ = write!(body, "<th>{}</th>", esc(h));
    }
    body.push_str("</tr></thead><tbody>");
    for r in rows {
        body.push_str("<tr>");
        for (k, _) in columns {
            let v = get(r, k);
            let is_rate = k.contains("rate")
                || k.starts_with("ci_")
                || k.starts_with("share")
                || k.contains("drop")
                || matches!(
                    *k,
                    "base" | "swap" | "object" | "lan" | "task" | "env" | "libero_pro_total" | "instruction_changed"
                );
            match v.parse::<f64>() {
                Ok(x) if is_rate => {
                    let _ = write!(body, "<td class=n>{}</td>", pct(x));
                }
                Ok(_) => {
                    let _ = write!(body, "<td class=n>{}</td>", esc(v));
                }
                Err(_) => {
                    let _ = write!(body, "<td>{}</td>", esc(v));
                }
            }
        }
        body.push_str("</tr>");
    }
    body.push_str("</tbody></table>");
}
