//! The commands of a Markdown file's shell blocks (```` ```sh ````,
//! ```` ```bash ````, ```` ```shell ````, ```` ```console ````), the markers
//! that skip some of them, and the tables the tree is checked against.
//!
//! A marker is an HTML comment right before a shell block (blank lines and
//! other markers may stand between):
//!
//! - `<!-- doc-test: skip — why -->` skips every command of the block;
//! - ``<!-- doc-test: skip `text` — why -->`` skips the commands of the
//!   block that contain `text`;
//! - `<!-- doc-test: feature bench -->` (or ``feature bench `text` ``, or
//!   `feature bench,zenoh`): the block's commands (containing `text`) need
//!   `skin` built with these cargo features; they run where the test is
//!   built with them, and are skipped, saying so, where it is not. A
//!   `cargo run ... -p skin --features F --` command says so itself.
//!
//! A marker anywhere else, a malformed one, or one whose `text` is in no
//! command of its block is a problem of the doc: a stale marker must not hide
//! a command that was added later.

/// One command of a shell block: what the doc says and what the test runs.
#[derive(Debug)]
pub struct DocCommand {
    /// The line of the doc where it starts (1-based).
    pub line: usize,
    /// Its first line as the doc writes it, for the summary.
    pub written: String,
    /// What runs (in bash): comments removed; `cargo run --release -p skin
    /// [--features F] --` and `./target/release/skin` written as `skin`
    /// (the built binary is `skin` on the test's PATH); a final `&` removed.
    pub shell: String,
    /// It ends with `&`: it keeps running while the doc's next commands run.
    pub background: bool,
    /// Why it is not run, from a marker; `None`: it runs.
    pub skip: Option<String>,
    /// The cargo features of `skin` it needs (a `feature` marker, or the
    /// `--features` of its `cargo run`).
    pub features: Vec<String>,
}

/// A doc's commands, in order, and what is wrong with its markers.
#[derive(Debug, Default)]
pub struct ParsedDoc {
    /// Every command of every shell block.
    pub commands: Vec<DocCommand>,
    /// Misplaced, malformed or stale markers, each naming its line.
    pub problems: Vec<String>,
}

/// A marker: for the whole block, or for its commands containing `needle`.
struct Marker {
    line: usize,
    needle: Option<String>,
    kind: MarkerKind,
}

/// What a marker says of the commands it applies to.
enum MarkerKind {
    /// They cannot run here, for this reason.
    Skip(String),
    /// They need `skin` built with these cargo features.
    Features(Vec<String>),
}

/// Reads the shell blocks of `text` (the doc `name`) and their markers.
pub fn parse(name: &str, text: &str) -> ParsedDoc {
    let mut doc = ParsedDoc::default();
    let mut pending: Vec<Marker> = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut at = 0;
    while at < lines.len() {
        let trimmed = lines[at].trim();
        if trimmed.starts_with("<!--") && trimmed.contains("doc-test:") {
            match parse_marker(trimmed) {
                Ok((needle, kind)) => pending.push(Marker { line: at + 1, needle, kind }),
                Err(why) => doc.problems.push(format!("{name}:{}: {why}", at + 1)),
            }
            at += 1;
            continue;
        }
        if let Some(fence) = trimmed.strip_prefix("```") {
            let language = fence.split([',', ' ']).next().unwrap_or("");
            let end = (at + 1..lines.len()).find(|&i| lines[i].trim().starts_with("```")).unwrap_or(lines.len());
            if matches!(language, "sh" | "bash" | "shell" | "console") {
                let body: Vec<(usize, &str)> = (at + 1..end).map(|i| (i + 1, lines[i])).collect();
                let mut commands = block_commands(&body, language == "console");
                apply_markers(name, &mut commands, std::mem::take(&mut pending), &mut doc.problems);
                doc.commands.extend(commands);
            }
            at = end + 1;
        } else {
            at += 1;
        }
        if !trimmed.is_empty() {
            for marker in pending.drain(..) {
                doc.problems
                    .push(format!("{name}:{}: a doc-test marker must stand right before a shell block", marker.line));
            }
        }
    }
    for marker in pending {
        doc.problems.push(format!("{name}:{}: a doc-test marker with no shell block after it", marker.line));
    }
    doc
}

/// `<!-- doc-test: skip [`text`] — reason -->` or `<!-- doc-test: feature
/// NAME[,NAME] [`text`] -->` as (needle, what it says).
fn parse_marker(comment: &str) -> Result<(Option<String>, MarkerKind), String> {
    let malformed = || {
        format!(
            "malformed marker {comment:?}: write <!-- doc-test: skip [`text`] — why --> or \
             <!-- doc-test: feature NAME [`text`] -->"
        )
    };
    let body = comment.split_once("doc-test:").map(|(_, b)| b).ok_or_else(malformed)?;
    let body = body.strip_suffix("-->").ok_or_else(malformed)?.trim();
    let (word, rest) = body.split_once(char::is_whitespace).ok_or_else(malformed)?;
    let (features, rest) = match word {
        "skip" => (None, rest.trim_start()),
        "feature" => {
            let (names, rest) = rest.trim_start().split_once(char::is_whitespace).unwrap_or((rest.trim(), ""));
            (Some(names.split(',').map(str::to_owned).collect::<Vec<_>>()), rest.trim_start())
        }
        _ => return Err(malformed()),
    };
    let (needle, rest) = match rest.strip_prefix('`') {
        Some(quoted) => {
            let (needle, rest) = quoted.split_once('`').ok_or_else(malformed)?;
            (Some(needle.to_owned()), rest.trim_start())
        }
        None => (None, rest),
    };
    if needle.as_deref() == Some("") {
        return Err(malformed());
    }
    if let Some(features) = features {
        if !rest.is_empty() || features.iter().any(String::is_empty) {
            return Err(malformed());
        }
        return Ok((needle, MarkerKind::Features(features)));
    }
    let reason = ["—", "–", "-", ":"].iter().find_map(|dash| rest.strip_prefix(dash)).ok_or_else(malformed)?.trim();
    if reason.is_empty() {
        return Err(malformed());
    }
    Ok((needle, MarkerKind::Skip(reason.to_owned())))
}

/// Gives each command the reason of the first skip marker that applies to
/// it, and the features of every feature marker that does.
fn apply_markers(name: &str, commands: &mut [DocCommand], markers: Vec<Marker>, problems: &mut Vec<String>) {
    for marker in markers {
        let mut used = false;
        for command in commands.iter_mut() {
            let applies = marker.needle.as_deref().is_none_or(|needle| command.written_in_full().contains(needle));
            if !applies {
                continue;
            }
            used = true;
            match &marker.kind {
                MarkerKind::Skip(reason) => {
                    command.skip.get_or_insert_with(|| reason.clone());
                }
                MarkerKind::Features(features) => {
                    for feature in features {
                        if !command.features.contains(feature) {
                            command.features.push(feature.clone());
                        }
                    }
                }
            }
        }
        if !used {
            problems.push(format!(
                "{name}:{}: the marker's `{}` is in no command of the block after it (stale marker?)",
                marker.line,
                marker.needle.as_deref().unwrap_or("")
            ));
        }
    }
}

impl DocCommand {
    /// What a marker's needle is matched against: the command as run, and
    /// as written (a needle may name a comment or the `cargo run` form).
    fn written_in_full(&self) -> String {
        format!("{}\n{}", self.written, self.shell)
    }
}

/// The commands of a block's lines: a command goes on over lines ending in
/// `\` and while a quote is open; full-line comments are dropped; in a
/// `console` block only lines starting with `$ ` start a command.
fn block_commands(body: &[(usize, &str)], console: bool) -> Vec<DocCommand> {
    let mut commands = Vec::new();
    let mut current: Option<(usize, String, String)> = None;
    for &(line, mut text) in body {
        let (start, mut raw, written) = match current.take() {
            Some(open) => open,
            None => {
                text = match text.trim_start().strip_prefix("$ ") {
                    Some(command) => command,
                    None if console => continue,
                    None => text,
                };
                if text.trim().is_empty() || text.trim_start().starts_with('#') {
                    continue;
                }
                (line, String::new(), text.trim().to_owned())
            }
        };
        if !raw.is_empty() {
            raw.push('\n');
        }
        raw.push_str(text);
        let (stripped, open_quote) = strip_comments(&raw);
        if open_quote || stripped.trim_end().ends_with('\\') {
            current = Some((start, raw, written));
        } else {
            commands.push(command(start, written, &stripped));
        }
    }
    if let Some((start, raw, written)) = current {
        // An unclosed quote: run it as written, and let bash say what is wrong.
        commands.push(command(start, written, &raw));
    }
    commands
}

fn command(line: usize, written: String, stripped: &str) -> DocCommand {
    let (mut shell, features) = written_as_skin(stripped.trim());
    let background = shell.ends_with('&') && !shell.ends_with("&&");
    if background {
        shell = shell.trim_end_matches('&').trim_end().to_owned();
    }
    DocCommand { line, written, shell, background, skip: None, features }
}

/// `text` without its shell comments (a `#` starting a word outside quotes,
/// to the end of its line), and whether a quote is still open at its end.
pub fn strip_comments(text: &str) -> (String, bool) {
    #[derive(PartialEq)]
    enum Quote {
        None,
        Single,
        Double,
    }
    let mut out = String::with_capacity(text.len());
    let mut quote = Quote::None;
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match (&quote, c) {
            (Quote::None, '#') if out.is_empty() || out.ends_with(char::is_whitespace) => {
                while chars.next_if(|&next| next != '\n').is_some() {}
                continue;
            }
            (Quote::None, '\'') => quote = Quote::Single,
            (Quote::None, '"') => quote = Quote::Double,
            (Quote::Single, '\'') | (Quote::Double, '"') => quote = Quote::None,
            (Quote::None | Quote::Double, '\\') => {
                out.push(c);
                if let Some(escaped) = chars.next() {
                    out.push(escaped);
                }
                continue;
            }
            _ => {}
        }
        out.push(c);
    }
    (out, quote != Quote::None)
}

/// The forms the docs write for the built binary, as `skin`, with the
/// features their `cargo run` asks for.
pub fn written_as_skin(command: &str) -> (String, Vec<String>) {
    let mut out = command.replace("./target/release/skin", "skin");
    let mut features = Vec::new();
    let cargo_run = "cargo run --release -p skin";
    while let Some(at) = out.find(cargo_run) {
        let Some(dashes) = out[at..].find(" -- ") else { break };
        let options: Vec<&str> = out[at + cargo_run.len()..at + dashes].split_whitespace().collect();
        for pair in options.windows(2).filter(|pair| pair[0] == "--features") {
            features.extend(pair[1].split(',').map(str::to_owned));
        }
        out.replace_range(at..at + dashes + " -- ".len(), "skin ");
    }
    (out, features)
}

/// One `skin` invocation inside a command: its arguments after `skin`.
#[derive(Debug, PartialEq)]
pub struct SkinCall {
    /// `["run", "examples/paper-virtual-skin.toml"]` for `skin run examples/paper-virtual-skin.toml`.
    pub args: Vec<String>,
}

/// Every `skin` invocation of `shell` (also inside `sh -c '...'`): a word
/// `skin` that starts a simple command, after environment assignments,
/// `sudo`, `exec` or `time`.
pub fn skin_calls(shell: &str) -> Vec<SkinCall> {
    let mut calls = Vec::new();
    for segment in shell.replace("\\\n", " ").split(['\n', ';', '|', '&', '(', ')']) {
        let words: Vec<String> = segment
            .split_whitespace()
            .map(|w| w.trim_matches(['\'', '"']).to_owned())
            .filter(|w| !w.is_empty())
            .take_while(|w| !w.starts_with('#'))
            .collect();
        let start = words.iter().position(|w| !(w.contains('=') || matches!(w.as_str(), "sudo" | "exec" | "time")));
        if let Some(start) = start.filter(|&s| words[s] == "skin") {
            calls.push(SkinCall { args: words[start + 1..].to_vec() });
        }
    }
    calls
}

impl SkinCall {
    /// The verb: `run` for `skin run CONFIG`.
    pub fn verb(&self) -> &str {
        self.args.first().map_or("", String::as_str)
    }

    fn has(&self, flag: &str) -> bool {
        self.args.iter().any(|a| a == flag || a.strip_prefix(flag).is_some_and(|rest| rest.starts_with('=')))
    }

    /// Runs until Ctrl-C (or for a long while): the test gives it a few
    /// seconds, it must still be alive, then it gets SIGINT.
    pub fn long_running(&self) -> bool {
        match self.verb() {
            "run" | "demo" | "view" | "emulate" | "replay" | "region" => true,
            "bridge" => !self.has("--seconds"),
            "top" => !self.has("--once"),
            "echo" => !self.has("--count"),
            "record" => !self.has("--recover"),
            _ => false,
        }
    }

    /// A long-running command that may also end by itself, with success,
    /// within the few seconds it is given (a short recording replayed,
    /// `--seconds`).
    pub fn may_end_by_itself(&self) -> bool {
        matches!(self.verb(), "record" | "region") || (self.verb() == "replay" && !self.has("--loop"))
    }

    /// Publishes channels under a skin name: another skin of the session
    /// (under the same name, most likely) is stopped first.
    pub fn starts_skin(&self) -> bool {
        matches!(self.verb(), "run" | "demo" | "replay")
    }

    /// Reads a running skin (a local one: not `--remote`).
    pub fn needs_skin(&self) -> bool {
        if self.has("--remote") {
            return false;
        }
        match self.verb() {
            "ls" | "top" | "echo" | "pull" | "services" | "view" | "region" | "bridge" => true,
            "record" => !self.has("--recover"),
            "geometry" => !self.args.iter().any(|a| a.ends_with(".toml")),
            _ => false,
        }
    }

    /// Starts a whole skin: the test waits until it is up (its geometry's
    /// layers all running, no new channel for a second).
    pub fn waits_until_up(&self) -> bool {
        matches!(self.verb(), "run" | "demo")
    }
}

/// The paths `text` names outside its fenced blocks: every link target
/// that is not a URL or an anchor (without its `#anchor`), and every
/// backticked path into the repository (`crates/`, `docs/`, `examples/`,
/// `fuzz/`, `.ci/`, possibly after `../`) that is not a pattern.
pub fn named_paths(text: &str) -> Vec<String> {
    let mut prose = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced {
            prose.push_str(line);
            prose.push('\n');
        }
    }
    let mut paths = Vec::new();
    for link in prose.split("](").skip(1) {
        let target = link.split([')', ' ']).next().unwrap_or("");
        let path = target.split('#').next().unwrap_or("");
        if !(path.is_empty() || path.contains("://") || path.starts_with("mailto:")) {
            paths.push(path.to_owned());
        }
    }
    for span in backticked(&prose) {
        let span = span.trim_end_matches(['.', ',', ':', ';']);
        let repo_path = ["crates/", "docs/", "examples/", "fuzz/", ".ci/"]
            .iter()
            .any(|top| span.trim_start_matches("../").starts_with(top));
        if repo_path && !span.contains(char::is_whitespace) && !span.contains(['*', '<', '{']) {
            paths.push(span.to_owned());
        }
    }
    paths
}

/// The rows of the first Markdown table of `text` whose header's first cell
/// is `first_header`: each row's cells, trimmed.
pub fn table_rows(text: &str, first_header: &str) -> Vec<Vec<String>> {
    let cells =
        |line: &str| -> Vec<String> { line.trim().trim_matches('|').split('|').map(|c| c.trim().to_owned()).collect() };
    let mut lines = text.lines().skip_while(|l| !(l.starts_with('|') && cells(l)[0] == first_header)).skip(2);
    let mut rows = Vec::new();
    for line in lines.by_ref() {
        if !line.starts_with('|') {
            break;
        }
        rows.push(cells(line));
    }
    rows
}

/// The text between backticks in `cell`: `` `python/` `` gives `python/`.
pub fn backticked(cell: &str) -> Vec<String> {
    cell.split('`').skip(1).step_by(2).map(str::to_owned).collect()
}

#[test]
fn commands_are_read_as_bash_would_and_markers_skip_what_they_name() {
    let doc = "intro\n\
        ```sh\n\
        cargo run --release -p skin -- demo   # the paper's skin\n\
        # a comment line\n\
        skin run a.toml &\n\
        ```\n\
        \n\
        <!-- doc-test: skip `--stats` — figures each second -->\n\
        <!-- doc-test: feature bench `bench follow` -->\n\
        \n\
        ```bash\n\
        cargo run --release -p skin --features zenoh -- bridge --stats\n\
        unshare -rn sh -c '\n  ip link add a type veth peer name b\n  skin run x.toml   # here\n'\n\
        ./target/release/skin bench follow --quick \\\n  --out DIR\n\
        ```\n\
        <!-- doc-test: skip — a second host -->\n\
        ```console\n\
        $ skin ls --remote robot-pc:7447\n\
        output line\n\
        ```\n";
    let parsed = parse("doc.md", doc);
    assert!(parsed.problems.is_empty(), "{:?}", parsed.problems);
    let shells: Vec<&str> = parsed.commands.iter().map(|c| c.shell.as_str()).collect();
    assert_eq!(shells[0], "skin demo");
    assert_eq!(shells[1], "skin run a.toml");
    assert_eq!(shells[2], "skin bridge --stats");
    assert_eq!(shells[3], "unshare -rn sh -c '\n  ip link add a type veth peer name b\n  skin run x.toml   # here\n'");
    assert_eq!(shells[4], "skin bench follow --quick \\\n  --out DIR");
    assert_eq!(shells[5], "skin ls --remote robot-pc:7447");
    assert_eq!(shells.len(), 6);
    let lines: Vec<usize> = parsed.commands.iter().map(|c| c.line).collect();
    assert_eq!(lines, [3, 5, 12, 13, 17, 22]);
    let features: Vec<&[String]> = parsed.commands.iter().map(|c| c.features.as_slice()).collect();
    assert_eq!(features, [&[][..], &[], &["zenoh".to_owned()], &[], &["bench".to_owned()], &[]]);
    let background: Vec<bool> = parsed.commands.iter().map(|c| c.background).collect();
    assert_eq!(background, [false, true, false, false, false, false]);
    let skips: Vec<Option<&str>> = parsed.commands.iter().map(|c| c.skip.as_deref()).collect();
    assert_eq!(skips, [None, None, Some("figures each second"), None, None, Some("a second host")]);
    let inner: Vec<Vec<SkinCall>> = parsed.commands.iter().map(|c| skin_calls(&c.shell)).collect();
    assert_eq!(inner[3], [SkinCall { args: vec!["run".into(), "x.toml".into()] }]);
    assert!(inner[3][0].long_running() && inner[3][0].starts_skin() && inner[3][0].waits_until_up());
    assert!(!inner[4][0].long_running() && !inner[5][0].needs_skin());
}

#[test]
fn misplaced_malformed_and_stale_markers_are_problems() {
    let doc = "<!-- doc-test: skip — nothing after it is a block -->\ntext\n\
        <!-- doc-test: skip `absent` — matches nothing -->\n```sh\nskin ls\n```\n\
        <!-- doc-test: skip without a reason -->\n```sh\nskin top\n```\n\
        <!-- doc-test: skip — a rust block is not a shell block -->\n```rust\nfn main() {}\n```\n\
        <!-- doc-test: feature bench — a feature marker has no reason -->\n```sh\nskin bench can\n```\n\
        <!-- doc-test: skip — at the end -->\n";
    let problems = parse("doc.md", doc).problems;
    assert_eq!(problems.len(), 6, "{problems:#?}");
    let lines = ["doc.md:1:", "doc.md:3:", "doc.md:7:", "doc.md:11:", "doc.md:15:", "doc.md:19:"];
    for (problem, line) in problems.iter().zip(lines) {
        assert!(problem.starts_with(line), "{problem} should be at {line}");
    }
}
