//! The docs match the tree (issue #38).
//!
//! - Every command of the shell blocks of `README.md`, `docs/*.md` and
//!   `examples/README.md` runs against this build's `skin`, in the order of
//!   its doc ([`session`] says how), unless a marker right before its block
//!   says why it cannot run here ([`markdown`] says how to write one): a new
//!   command is tested unless someone writes down why not. Skipped `skin`
//!   commands are still parsed (`--help` after them). Commands that need
//!   `skin` built with a cargo feature (`bench`, `zenoh`) run where this test
//!   is built with it, and are skipped, saying so, where it is not. The test
//!   prints what it ran and skipped, and why.
//! - `examples/README.md`'s table lists every file and folder of `examples/`
//!   (and each folder's row names its files), and the README's layout table
//!   links every `docs/*.md`, with nothing listed that is not there; every
//!   path the docs name (links, backticked repository paths) exists.

mod markdown;
mod session;

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use markdown::{backticked, named_paths, parse, table_rows};
use session::{Outcome, Session, Verdict};

use crate::util::one_skin_at_a_time;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").canonicalize().unwrap()
}

/// The docs whose commands run: the README, every `docs/*.md`, the examples' README.
fn docs(repo: &Path) -> Vec<String> {
    let mut under_docs: Vec<String> = std::fs::read_dir(repo.join("docs"))
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.ends_with(".md"))
        .map(|name| format!("docs/{name}"))
        .collect();
    under_docs.sort();
    let mut all = vec!["README.md".to_owned()];
    all.extend(under_docs);
    all.push("examples/README.md".to_owned());
    all
}

/// Whether a command can have a network namespace of its own here (a user
/// namespace's root, with its loopback up): then the docs' fixed ports
/// (8080, 7447) cannot meet another program's.
fn private_network_works() -> bool {
    std::process::Command::new("unshare")
        .args(["-rn", "sh", "-c", "ip link set lo up"])
        .output()
        .is_ok_and(|output| output.status.success())
}

#[test]
fn every_documented_command_runs_or_says_why_not() {
    let _alone = one_skin_at_a_time();
    let started = Instant::now();
    let repo = repo();
    let netns = private_network_works();
    let mut failures = Vec::new();
    let (mut details, mut counts) = (String::new(), String::new());
    let (mut ran, mut skipped) = (0, 0);
    for (index, name) in docs(&repo).into_iter().enumerate() {
        let parsed = parse(&name, &std::fs::read_to_string(repo.join(&name)).unwrap());
        failures.extend(parsed.problems);
        let mut session = Session::new(&name, index, &repo, netns);
        for command in &parsed.commands {
            session.run(command);
        }
        let outcomes = session.finish();
        let (doc_ran, doc_skipped) = summarise(&name, &outcomes, &mut details, &mut failures);
        counts.push_str(&format!(
            "docs: {name}: {doc_ran} ran, {doc_skipped} skipped, {} failed\n",
            outcomes.len() - doc_ran - doc_skipped
        ));
        ran += doc_ran;
        skipped += doc_skipped;
    }
    counts.push_str(&format!(
        "docs: {ran} commands ran, {skipped} skipped, {} problems, in {:.0} s ({})\n",
        failures.len(),
        started.elapsed().as_secs_f64(),
        if netns { "each in a network namespace of its own" } else { "no private network namespace here" }
    ));
    // Every command's line is printed as tests print (shown with
    // --nocapture or on failure); the counts always, past the capture.
    println!("{details}");
    let _ = std::io::stderr().write_all(counts.as_bytes());
    assert!(failures.is_empty(), "the docs do not match the tree:\n{}", failures.join("\n"));
}

/// Adds a line per command of a doc to `details` and its failures to
/// `failures`; gives how many commands ran and how many were skipped.
fn summarise(name: &str, outcomes: &[Outcome], details: &mut String, failures: &mut Vec<String>) -> (usize, usize) {
    let ran = outcomes.iter().filter(|o| matches!(o.verdict, Verdict::Ran(_))).count();
    let skipped = outcomes.iter().filter(|o| matches!(o.verdict, Verdict::Skipped(_))).count();
    for outcome in outcomes {
        let (word, detail) = match &outcome.verdict {
            Verdict::Ran(detail) => ("ran    ", detail),
            Verdict::Skipped(reason) => ("skipped", reason),
            Verdict::Failed(failure) => ("FAILED ", failure),
        };
        let line = format!("  {word} {name}:{} `{}`: {detail}\n", outcome.line, outcome.written);
        if matches!(outcome.verdict, Verdict::Failed(_)) {
            failures.push(line.trim_end().to_owned());
        }
        details.push_str(&line);
    }
    (ran, skipped)
}

#[test]
fn every_marker_stands_before_a_block_and_skips_something() {
    let repo = repo();
    let problems: Vec<String> = docs(&repo)
        .iter()
        .flat_map(|name| parse(name, &std::fs::read_to_string(repo.join(name)).unwrap()).problems)
        .collect();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The names in `examples/` (folders with a `/`), but its README.
fn examples_in_tree(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            if e.file_type().unwrap().is_dir() { format!("{name}/") } else { name }
        })
        .filter(|name| name != "README.md")
        .collect()
}

#[test]
fn the_examples_table_lists_every_example() {
    let examples = repo().join("examples");
    let readme = std::fs::read_to_string(examples.join("README.md")).unwrap();
    let rows = table_rows(&readme, "file");
    assert!(!rows.is_empty(), "examples/README.md has no table whose first column is `file`");
    let listed: BTreeSet<String> = rows.iter().flat_map(|row| backticked(&row[0])).collect();
    let in_tree = examples_in_tree(&examples);
    let missing: Vec<&String> = in_tree.difference(&listed).collect();
    let stale: Vec<&String> = listed.difference(&in_tree).collect();
    assert!(missing.is_empty(), "examples/ has {missing:?}, which examples/README.md's table does not list");
    assert!(stale.is_empty(), "examples/README.md's table lists {stale:?}, which examples/ does not have");
    for row in rows.iter().filter(|row| row[0].ends_with("/`")) {
        let folder = backticked(&row[0]).remove(0);
        let named: BTreeSet<String> = row[1..].iter().flat_map(|cell| backticked(cell)).collect();
        for file in examples_in_tree(&examples.join(&folder)) {
            assert!(named.contains(&file), "examples/{folder}{file} is not named in the table's row of `{folder}`");
        }
    }
}

#[test]
fn the_readme_layout_links_every_doc() {
    let repo = repo();
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    let row = table_rows(&readme, "crate")
        .into_iter()
        .find(|row| row[0] == "`docs/`")
        .expect("README.md's layout table (first column `crate`) has no row `docs/`");
    let linked: BTreeSet<String> = row[1]
        .split("](docs/")
        .skip(1)
        .filter_map(|rest| rest.split_once(')'))
        .map(|(target, _)| target.to_owned())
        .filter(|target| !target.contains('/'))
        .collect();
    let in_tree: BTreeSet<String> =
        docs(&repo).iter().filter_map(|d| d.strip_prefix("docs/")).map(str::to_owned).collect();
    let missing: Vec<&String> = in_tree.difference(&linked).collect();
    let stale: Vec<&String> = linked.difference(&in_tree).collect();
    assert!(missing.is_empty(), "docs/ has {missing:?}, which the README's `docs/` row does not link");
    assert!(stale.is_empty(), "the README's `docs/` row links {stale:?}, which docs/ does not have");
}

#[test]
fn every_path_the_docs_name_exists() {
    let repo = repo();
    let mut missing = Vec::new();
    for name in docs(&repo) {
        let text = std::fs::read_to_string(repo.join(&name)).unwrap();
        let here = repo.join(&name).parent().unwrap().to_owned();
        for path in named_paths(&text) {
            // Links are relative to the doc; backticked paths, to the
            // repository (or, after `../`, to the doc).
            if !here.join(&path).exists() && !repo.join(&path).exists() {
                missing.push(format!("{name}: {path}"));
            }
        }
    }
    assert!(missing.is_empty(), "the docs name paths that are not in the tree:\n{}", missing.join("\n"));
}
