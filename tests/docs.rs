//! The documents cannot rot: the docs book builds with mdBook, and every relative link and
//! anchor in README.md, ARCHITECTURE.md and the book's pages points at a file and a heading that
//! exist. Links to the web (`https://...`) are not followed (CI has no network).

use libero_e2e::{repo_root, test_dir};
use pulldown_cmark::{Event, Options, Parser, Tag, TagEnd};
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

/// The documents whose links are checked: the README, the code map and every page of the book.
pub(crate) fn documents() -> Vec<PathBuf> {
    let root = repo_root();
    let mut docs = vec![root.join("README.md"), root.join("ARCHITECTURE.md")];
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root.join("docs/src"))
        .expect("docs/src")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    docs.extend(pages);
    docs
}

/// The Markdown extensions GitHub and mdBook render (tables, footnotes, strikethrough, task lists).
pub(crate) fn markdown_options() -> Options {
    Options::ENABLE_TABLES | Options::ENABLE_FOOTNOTES | Options::ENABLE_STRIKETHROUGH | Options::ENABLE_TASKLISTS
}

/// One Markdown file: the anchors its headings make, and the links it holds (with their lines).
struct Document {
    anchors: HashSet<String>,
    links: Vec<(usize, String)>,
}

fn read_document(path: &Path) -> Document {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let line_of = |offset: usize| text[..offset].matches('\n').count() + 1;
    let mut anchors = HashSet::new();
    let mut links = Vec::new();
    let mut heading: Option<String> = None;
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (event, range) in Parser::new_ext(&text, markdown_options()).into_offset_iter() {
        match event {
            Event::Start(Tag::Heading { .. }) => heading = Some(String::new()),
            Event::Text(t) | Event::Code(t) if heading.is_some() => heading.as_mut().unwrap().push_str(&t),
            Event::End(TagEnd::Heading(_)) => {
                let slug = slug(&heading.take().unwrap());
                // Repeated headings get -1, -2, ... (as GitHub and mdBook number them).
                let n = seen.entry(slug.clone()).or_insert(0);
                anchors.insert(if *n == 0 { slug } else { format!("{slug}-{n}") });
                *n += 1;
            }
            Event::Start(Tag::Link { dest_url, .. }) | Event::Start(Tag::Image { dest_url, .. }) => {
                links.push((line_of(range.start), dest_url.to_string()))
            }
            _ => {}
        }
    }
    Document { anchors, links }
}

/// A heading's anchor as GitHub and mdBook make it: lower case, whitespace to `-`, every character
/// other than letters, digits, `-` and `_` dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .chars()
        .filter_map(|c| match c {
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c.to_lowercase().next().unwrap()),
            c if c.is_whitespace() => Some('-'),
            _ => None,
        })
        .collect()
}

/// Every problem with `link` as written in `from` (empty when it resolves).
fn check_link(from: &Path, link: &str, documents: &mut BTreeMap<PathBuf, Document>) -> Option<String> {
    if link.contains("://") || link.starts_with("mailto:") {
        return None;
    }
    let (path, anchor) = match link.split_once('#') {
        Some((p, a)) => (p, Some(a)),
        None => (link, None),
    };
    let target = if path.is_empty() { from.to_path_buf() } else { from.parent().unwrap().join(path) };
    if !target.exists() {
        return Some(format!("{path} does not exist"));
    }
    let anchor = anchor?;
    if target.extension().is_none_or(|e| e != "md") {
        return Some(format!("an anchor (#{anchor}) into {path}, which is not Markdown"));
    }
    let target = target.canonicalize().unwrap();
    let doc = documents.entry(target.clone()).or_insert_with(|| read_document(&target));
    (!doc.anchors.contains(anchor)).then(|| {
        let mut known: Vec<_> = doc.anchors.iter().cloned().collect();
        known.sort();
        format!("no heading makes #{anchor} in {} (its anchors: {})", target.display(), known.join(", "))
    })
}

#[test]
fn every_relative_link_and_anchor_resolves() {
    let mut documents: BTreeMap<PathBuf, Document> = BTreeMap::new();
    let mut broken = Vec::new();
    let mut checked = 0;
    for path in self::documents() {
        let links = read_document(&path).links;
        for (line, link) in links {
            checked += 1;
            if let Some(problem) = check_link(&path, &link, &mut documents) {
                let shown = path.strip_prefix(repo_root()).unwrap_or(&path).display().to_string();
                broken.push(format!("{shown}:{line}: ({link}) {problem}"));
            }
        }
    }
    assert!(checked > 100, "only {checked} links found: is the parser reading the documents?");
    assert!(broken.is_empty(), "{} broken links:\n{}", broken.len(), broken.join("\n"));
}

#[test]
fn a_broken_link_and_a_missing_anchor_are_found() {
    let dir = test_dir("docs", "broken_links");
    let page = dir.join("page.md");
    std::fs::write(
        &page,
        "# A page\n\n## Second part\n\n[ok](#second-part) [gone](missing.md) [no anchor](#third-part) \
         [web](https://example.com/x)\n",
    )
    .unwrap();
    let mut documents = BTreeMap::new();
    let problems: Vec<_> =
        read_document(&page).links.iter().map(|(_, link)| check_link(&page, link, &mut documents)).collect();
    assert!(problems[0].is_none(), "{problems:?}");
    assert!(problems[1].as_deref().unwrap().contains("does not exist"), "{problems:?}");
    assert!(problems[2].as_deref().unwrap().contains("#third-part"), "{problems:?}");
    assert!(problems[3].is_none(), "{problems:?}");
    assert_eq!(slug("`pipeline specs` and the A/B (≤ 5%)"), "pipeline-specs-and-the-ab--5");
}

/// The book builds (every page of SUMMARY.md exists: `create-missing = false`) and every page of
/// SUMMARY.md comes out as HTML.
#[test]
fn the_docs_book_builds() {
    let out = test_dir("docs", "book");
    let mut book = mdbook_driver::MDBook::load(repo_root().join("docs")).unwrap_or_else(|e| panic!("docs/: {e:#}"));
    book.config.build.build_dir = out.clone();
    book.build().unwrap_or_else(|e| panic!("mdbook build docs: {e:#}"));
    let summary = std::fs::read_to_string(repo_root().join("docs/src/SUMMARY.md")).unwrap();
    let mut pages = 0;
    for (i, _) in summary.match_indices("](") {
        let target = &summary[i + 2..];
        let page = &target[..target.find(')').unwrap()];
        let html = out.join(page.replace(".md", ".html"));
        assert!(html.exists(), "{} was not built", html.display());
        pages += 1;
    }
    assert!(pages >= 15, "SUMMARY.md lists {pages} pages");
}

#[test]
fn headings_make_distinct_anchors() {
    let page = test_dir("docs", "anchors").join("page.md");
    std::fs::write(&page, "# T\n\n## Limits\n\n## Limits\n\n## `a.sql`\n").unwrap();
    let anchors = read_document(&page).anchors;
    for a in ["t", "limits", "limits-1", "asql"] {
        assert!(anchors.contains(a), "{a} not in {anchors:?}");
    }
}
