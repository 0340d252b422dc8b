//! The documentation cannot rot quietly: every relative link and image in README.md and docs/**/*.md points at a
//! file that exists (and, with a `#fragment`, at a heading of that file), and every `r2human …` command line in the
//! README's code blocks parses with the real command-line definition (`r2human::cli::Cli`). Nothing here loads a
//! model or runs a command, so the test takes milliseconds.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use clap::Parser;
use r2human::cli::Cli;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// README.md and every Markdown file under docs/.
fn doc_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir).expect("docs/ is readable").flatten().collect();
        entries.sort_by_key(|e| e.path());
        for e in entries {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "md") {
                out.push(p);
            }
        }
    }
    let mut files = vec![root().join("README.md")];
    walk(&root().join("docs"), &mut files);
    files
}

/// The lines of a Markdown file with their numbers and whether they lie inside a fenced code block; the fence
/// lines themselves are left out.
fn lines_by_fence(text: &str) -> Vec<(usize, bool, &str)> {
    let mut out = Vec::new();
    let mut fenced = false;
    for (i, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else {
            out.push((i + 1, fenced, line));
        }
    }
    out
}

/// The text of a Markdown file without fenced code blocks and inline code spans (links there are not links),
/// line by line: (line number, text).
fn prose_lines(text: &str) -> Vec<(usize, String)> {
    lines_by_fence(text)
        .into_iter()
        .filter(|&(_, fenced, _)| !fenced)
        // Drop inline code spans: every other piece between backticks.
        .map(|(n, _, line)| (n, line.split('`').step_by(2).collect::<Vec<_>>().join(" ")))
        .collect()
}

/// The targets of the inline links and images of one line: `[text](target)` and `![alt](target)`, with an
/// optional title (`[t](target "title")`) dropped.
fn link_targets(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let end = rest.find(')').unwrap_or(rest.len());
        let target = rest[..end].split_whitespace().next().unwrap_or("");
        let target = target.trim_start_matches('<').trim_end_matches('>');
        if !target.is_empty() {
            out.push(target.to_string());
        }
        rest = &rest[end..];
    }
    out
}

/// GitHub's anchor of a heading: lower case, spaces to hyphens, everything but letters, digits, `-` and `_`
/// dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a Markdown file's headings (outside code blocks).
fn anchors(text: &str) -> BTreeSet<String> {
    lines_by_fence(text)
        .into_iter()
        .filter(|&(_, fenced, line)| !fenced && line.starts_with('#'))
        .map(|(_, _, line)| slug(line.trim_start_matches('#')))
        .collect()
}

#[test]
fn every_relative_link_and_image_resolves() {
    let files = doc_files();
    assert!(files.len() > 5, "README.md and the pages of docs/ are found: {files:?}");
    let mut broken = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("a readable Markdown file");
        let here = file.parent().expect("a file has a folder");
        for (line_no, line) in prose_lines(&text) {
            for target in link_targets(&line) {
                if target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                let (path, fragment) = match target.split_once('#') {
                    Some((p, f)) => (p, Some(f)),
                    None => (target.as_str(), None),
                };
                let resolved = if path.is_empty() { file.clone() } else { here.join(path) };
                let name = file.strip_prefix(root()).unwrap_or(file).display();
                if !resolved.exists() {
                    broken.push(format!("{name}:{line_no}: `{target}` does not exist"));
                    continue;
                }
                if let Some(fragment) = fragment {
                    if resolved.extension().is_some_and(|x| x == "md") {
                        let target_text = std::fs::read_to_string(&resolved).expect("a readable Markdown file");
                        if !anchors(&target_text).contains(fragment) {
                            broken.push(format!("{name}:{line_no}: `{target}`: no heading with that anchor"));
                        }
                    }
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links in the documentation:\n{}", broken.join("\n"));
}

/// The `r2human …` command lines of the README's code blocks, comments after ` #` cut, split on whitespace (the
/// README's commands use no shell quoting).
fn readme_commands(readme: &str) -> Vec<(usize, Vec<String>)> {
    lines_by_fence(readme)
        .into_iter()
        .filter(|&(_, fenced, line)| fenced && line.trim().starts_with("r2human "))
        .map(|(n, _, line)| {
            let line = line.trim();
            let command = line.split(" #").next().unwrap_or(line);
            (n, command.split_whitespace().map(str::to_string).collect())
        })
        .collect()
}

#[test]
fn every_command_of_the_readme_parses() {
    let readme = std::fs::read_to_string(root().join("README.md")).expect("README.md");
    let commands = readme_commands(&readme);
    // The tour has one example each for: photo → views, the window, the headset, glTF export, eval.
    for sub in ["render", "view", "xr", "export", "eval"] {
        assert!(
            commands.iter().any(|(_, c)| c.get(1).is_some_and(|s| s == sub)),
            "the README's tour shows no `r2human {sub} …` command"
        );
    }
    let failed: Vec<String> = commands
        .iter()
        .filter_map(|(line, args)| {
            Cli::try_parse_from(args).err().map(|e| format!("README.md:{line}: `{}`:\n{e}", args.join(" ")))
        })
        .collect();
    assert!(failed.is_empty(), "README commands that do not parse:\n{}", failed.join("\n"));
}

#[test]
fn the_readers_work_on_small_cases() {
    assert_eq!(link_targets("see [a](docs/a.md) and ![b](img.png \"t\")"), ["docs/a.md", "img.png"]);
    assert_eq!(link_targets("no links (here) [x] (y)"), Vec::<String>::new());
    assert_eq!(slug("The person-renderer seam"), "the-person-renderer-seam");
    assert_eq!(slug("Measured (lavapipe, no GPU)"), "measured-lavapipe-no-gpu");
    let prose = prose_lines("a `[x](nowhere)` b\n```\n[y](nowhere)\n```\n[z](here.md)\n");
    let targets: Vec<String> = prose.iter().flat_map(|(_, l)| link_targets(l)).collect();
    assert_eq!(targets, ["here.md"]);
    let commands = readme_commands("```sh\nr2human view --camera 0   # a camera\ncargo run\n```\nr2human x\n");
    assert_eq!(commands, [(2, vec!["r2human".to_string(), "view".into(), "--camera".into(), "0".into()])]);
}
