//! `pipeline cli-reference` (hidden): the command line's reference page, `docs/src/cli.md`, made
//! from clap's own command tree, so it says what `--help` says. An end-to-end test
//! (`tests/cli.rs`) fails when the page and the binary differ.

use clap::Command;

/// The page's line width.
const WIDTH: usize = 100;

/// The page: a title, one line on where it comes from, then the top-level help and each visible
/// subcommand's long help (`--help`; `bench`'s subcommands too), without styling, its lines
/// wrapped at [`WIDTH`] (a terminal wraps them itself; a code block on a page would scroll).
pub fn markdown(cmd: Command) -> String {
    // the same page wherever it is made: a fixed width (no terminal's), no environment's values
    let mut cmd = cmd.term_width(WIDTH).mut_arg("bundles", |a| a.hide_env_values(true));
    cmd.build();
    let mut out = String::from(
        "# Command line\n\n\
         Generated from the binary's own `--help` by `pipeline cli-reference` (do not edit it by hand);\n\
         a test checks that it is current.\n",
    );
    section(&mut out, "pipeline", &mut cmd);
    out
}

fn section(out: &mut String, path: &str, cmd: &mut Command) {
    let help = cmd.render_long_help().to_string();
    out.push_str(&format!("\n## {path}\n\n```text\n"));
    for line in help.trim_end().lines() {
        wrap(out, line.trim_end());
    }
    out.push_str("```\n");
    for sub in cmd.get_subcommands_mut() {
        if sub.is_hide_set() || sub.get_name() == "help" {
            continue;
        }
        let path = format!("{path} {}", sub.get_name());
        section(out, &path, sub);
    }
}

/// Push `line`, wrapped at [`WIDTH`] on spaces: continuation lines are indented to where its text
/// starts, the description's column for `  name    description`, `  --flag <V>  description` and
/// `- value: description`.
fn wrap(out: &mut String, line: &str) {
    if line.chars().count() <= WIDTH {
        out.push_str(line);
        out.push('\n');
        return;
    }
    let lead = line.len() - line.trim_start().len();
    let text_column = line[lead..].find("  ").map(|gap| {
        let text = lead + gap + line[lead + gap..].len() - line[lead + gap..].trim_start().len();
        line[..text].chars().count()
    });
    // a list item `- name: text` (clap's possible values): under its text, else after the `- `
    let item = line[lead..].strip_prefix("- ").map(|rest| match rest.find(": ") {
        Some(colon) => lead + 2 + colon + 1 + rest[colon + 1..].len() - rest[colon + 1..].trim_start().len(),
        None => lead + 2,
    });
    let text_column = item.or(text_column);
    let indent = " ".repeat(text_column.filter(|&c| c < WIDTH / 2).unwrap_or(lead));
    let mut current = line[..lead].to_string();
    let (mut has_word, mut spaces) = (false, 0);
    for word in line[lead..].split(' ') {
        if word.is_empty() {
            spaces += 1; // a run of spaces within the line is kept
            continue;
        }
        let sep = if has_word { 1 + spaces } else { 0 };
        if has_word && current.chars().count() + sep + word.chars().count() > WIDTH {
            out.push_str(&current);
            out.push('\n');
            current = indent.clone();
        } else {
            current.push_str(&" ".repeat(sep));
        }
        current.push_str(word);
        (has_word, spaces) = (true, 0);
    }
    out.push_str(&current);
    out.push('\n');
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every example line of every command's `--help` (`pipeline ...`, up to a `#` comment; each
    /// side of `&&`) parses: its subcommand, flags and values exist.
    #[test]
    fn every_example_parses() {
        fn collect(cmd: &Command, out: &mut Vec<String>) {
            for line in cmd.get_after_help().map(|h| h.to_string()).unwrap_or_default().lines() {
                let line = line.split(" # ").next().unwrap_or_default().trim();
                if line.starts_with("pipeline ") {
                    out.extend(line.split(" && ").map(|c| c.trim().replace("$(hostname)", "node1")));
                }
            }
            for sub in cmd.get_subcommands() {
                collect(sub, out);
            }
        }
        let mut examples = Vec::new();
        collect(&<crate::Cli as clap::CommandFactory>::command(), &mut examples);
        assert!(examples.len() >= 40, "{examples:?}");
        for example in examples {
            // shell words: split on spaces outside quotes
            let (mut words, mut word, mut quote) = (Vec::new(), String::new(), None);
            for c in example.chars() {
                match (c, quote) {
                    ('\'' | '"', None) => quote = Some(c),
                    (c, Some(q)) if c == q => quote = None,
                    (' ', None) => words.extend((!word.is_empty()).then(|| std::mem::take(&mut word))),
                    (c, _) => word.push(c),
                }
            }
            words.extend((!word.is_empty()).then_some(word));
            if let Err(e) = <crate::Cli as clap::Parser>::try_parse_from(&words) {
                panic!("example `{example}` does not parse: {e}");
            }
        }
    }

    #[test]
    fn long_lines_wrap_under_their_text() {
        let mut out = String::new();
        let words = "word ".repeat(30);
        wrap(&mut out, &format!("      --flag <V>  {words}"));
        let lines: Vec<&str> = out.lines().collect();
        assert!(lines.len() > 1 && lines.iter().all(|l| l.len() <= WIDTH), "{out}");
        assert!(lines[1].starts_with(&" ".repeat(18)) && !lines[1].starts_with(&" ".repeat(19)), "{out}");
        let mut out = String::new();
        wrap(&mut out, &format!("          - last-step: {words}"));
        assert!(out.lines().nth(1).unwrap().starts_with(&format!("{}word", " ".repeat(23))), "{out}");
        let mut out = String::new();
        wrap(&mut out, &format!("  {words}{words}"));
        assert!(out.lines().skip(1).all(|l| l.starts_with("  word")), "{out}");
    }
}
