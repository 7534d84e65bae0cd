//! The guide cannot rot: the README's quickstart blocks (fenced as `bash quickstart`) run through
//! the real binary on a small setting, and every `pipeline` flag written in a shell block or an
//! inline command of the README and the book exists in that subcommand's `--help`. A renamed flag
//! or subcommand fails here, not in a user's terminal.

use libero_e2e::{pipeline, pipeline_bin, repo_root, test_dir};
use pulldown_cmark::{CodeBlockKind, Event, Parser, Tag, TagEnd};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The README, the code map and the book's pages, except the page generated from the help itself.
fn documents() -> Vec<PathBuf> {
    crate::docs::documents().into_iter().filter(|p| !p.ends_with("cli.md")).collect()
}

/// The fenced code blocks of a Markdown text: (info string, code).
fn code_blocks(markdown: &str) -> Vec<(String, String)> {
    let mut blocks = Vec::new();
    let mut open: Option<(String, String)> = None;
    for event in Parser::new_ext(markdown, crate::docs::markdown_options()) {
        match event {
            Event::Start(Tag::CodeBlock(CodeBlockKind::Fenced(info))) => open = Some((info.to_string(), String::new())),
            Event::Text(t) if open.is_some() => open.as_mut().unwrap().1.push_str(&t),
            Event::End(TagEnd::CodeBlock) => blocks.extend(open.take()),
            _ => {}
        }
    }
    blocks
}

/// The shell commands a document writes: its `bash`/`sh` blocks' lines (continuations joined)
/// and its inline code spans that start with `pipeline `.
fn shell_commands(markdown: &str) -> Vec<String> {
    let mut commands = Vec::new();
    for (info, code) in code_blocks(markdown) {
        if info.starts_with("bash") || info.starts_with("sh") {
            commands.extend(code.replace("\\\n", " ").lines().map(str::to_string));
        }
    }
    for event in Parser::new_ext(markdown, crate::docs::markdown_options()) {
        if let Event::Code(code) = event
            && code.starts_with("pipeline ")
        {
            commands.push(code.to_string());
        }
    }
    commands
}

/// Each `pipeline` invocation in a command line: (subcommand path, flags), up to the end of that
/// invocation (`;`, `|`, `&&`, a comment).
fn invocations(line: &str) -> Vec<(Vec<String>, Vec<String>)> {
    // a comment ends the command line
    let tokens: Vec<&str> = line.split_whitespace().take_while(|t| !t.starts_with('#')).collect();
    let word = |t: &str| !t.is_empty() && t.chars().all(|c| c.is_ascii_lowercase() || c == '-');
    let mut found = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        let is_binary = tokens[i] == "pipeline" || tokens[i].ends_with("/pipeline");
        i += 1;
        if !is_binary {
            continue;
        }
        // the subcommand is the word right after the binary (`bench`'s, the word after that)
        let mut path = Vec::new();
        while i < tokens.len() && word(tokens[i]) && (path.is_empty() || path == ["bench"]) {
            path.push(tokens[i].to_string());
            i += 1;
        }
        let mut flags = Vec::new();
        while i < tokens.len() {
            let t = tokens[i].trim_matches(|c| c == '"' || c == '\'' || c == '`' || c == '(' || c == ')');
            if [";", "|", "&&", "||", "&", "done"].contains(&t) || tokens[i].ends_with(';') {
                break;
            }
            if let Some(name) = t.strip_prefix("--").map(|f| f.split('=').next().unwrap())
                && word(name)
            {
                flags.push(format!("--{name}"));
            }
            i += 1;
        }
        if !path.is_empty() || !flags.is_empty() {
            found.push((path, flags));
        }
    }
    found
}

#[test]
fn every_pipeline_flag_written_in_the_documents_exists() {
    let mut help: BTreeMap<Vec<String>, Result<String, String>> = BTreeMap::new();
    let mut problems = Vec::new();
    let mut checked = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).unwrap();
        let shown = doc.strip_prefix(repo_root()).unwrap().display().to_string();
        for command in shell_commands(&text) {
            for (path, flags) in invocations(&command) {
                if path.is_empty() {
                    continue; // `pipeline --help`, or the word in prose
                }
                let text = help.entry(path.clone()).or_insert_with(|| help_text(&path));
                let text = match text {
                    Ok(t) => t,
                    Err(e) => {
                        problems.push(format!("{shown}: `{command}`: {e}"));
                        continue;
                    }
                };
                for flag in flags {
                    checked += 1;
                    if !text.contains(&format!("{flag} "))
                        && !text.contains(&format!("{flag}\n"))
                        && !text.contains(&format!("{flag}="))
                        && !text.contains(&format!("{flag},"))
                    {
                        problems.push(format!("{shown}: `{command}`: pipeline {} has no {flag}", path.join(" ")));
                    }
                }
            }
        }
    }
    assert!(checked > 100, "only {checked} flags found in the documents: is the extraction broken?");
    assert!(problems.is_empty(), "{} commands in the documents do not parse:\n{}", problems.len(), problems.join("\n"));
}

fn help_text(path: &[String]) -> Result<String, String> {
    let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
    args.push("--help");
    let out = pipeline(&args);
    if out.status.success() {
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    } else {
        Err(format!("`pipeline {}` is not a subcommand", path.join(" ")))
    }
}

#[test]
fn the_flag_check_finds_a_renamed_flag() {
    let found = invocations("pipeline results --run runs/a --succes last-step   # re-score; pipeline sql x --csv");
    assert_eq!(found, [(vec!["results".to_string()], vec!["--run".to_string(), "--succes".to_string()])]);
    let found = invocations(r#"for p in a b; do pipeline run s.parquet --out runs/$p --policy $p; done"#);
    assert_eq!(found[0].0, ["run"]);
    assert_eq!(found[0].1, ["--out", "--policy"]);
    assert_eq!(invocations("pipeline bench sim --steps 10")[0].0, ["bench", "sim"]);
    assert!(invocations("`pipeline → udfs → sim`").is_empty(), "prose is no command");
    let help = help_text(&["results".to_string()]).unwrap();
    assert!(help.contains("--run ") && !help.contains("--succes "), "{help}");
}

/// What the quickstart blocks are run with instead of their full-size settings. Each must match
/// the README at least once, so a README edit that drops one fails here and the list follows it.
fn substitutions(checkpoint: &Path) -> Vec<(&'static str, String)> {
    vec![
        ("CKPT=~/models/openvla-7b-finetuned-libero-spatial", format!("CKPT={}", checkpoint.display())),
        ("--trials 50", "--trials 1 --tasks 0".into()),
        // a random-weight model: 3 policy steps prove the path; the cap is not the point here
        ("--jobs 32", "--jobs 2 --max-steps 3".into()),
        ("batch=32", "batch=2".into()),
    ]
}

#[test]
fn the_readme_quickstart_runs_on_a_small_setting() {
    let dir = test_dir("readme", "quickstart");
    let checkpoint = crate::openvla::tiny_checkpoint(&dir);
    let readme = std::fs::read_to_string(repo_root().join("README.md")).unwrap();
    let mut script = String::from("set -euo pipefail\n");
    let mut blocks = 0;
    for (info, code) in code_blocks(&readme) {
        if info.split_whitespace().any(|w| w == "quickstart") {
            script.push_str(&code);
            blocks += 1;
        }
    }
    assert!(blocks >= 3, "the README has {blocks} quickstart blocks");
    for (from, to) in substitutions(&checkpoint) {
        assert!(script.contains(from), "the README's quickstart no longer has {from:?}: update substitutions()");
        script = script.replace(from, &to);
    }
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let bin_dir = pipeline_bin().parent().unwrap().to_path_buf();
    let path = format!("{}:{}", bin_dir.display(), std::env::var("PATH").unwrap_or_default());
    let out = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(&work)
        .env("PATH", path)
        .env("LIBERO_BUNDLES", repo_root().join("data/bundles"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the README's quickstart failed:\n{script}\nstdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    for made in [
        "runs/openvla-spatial/manifest.json",
        "outputs/results.csv",
        "outputs/report.html",
        "outputs/failure_modes.csv",
    ] {
        assert!(work.join(made).exists(), "the quickstart made no {made}");
    }
    let results = std::fs::read_to_string(work.join("outputs/results.csv")).unwrap();
    assert!(results.contains("ci_lo") && results.contains("libero_spatial"), "{results}");
}
