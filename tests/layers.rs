//! The layer table of docs/architecture.md is the law of the imports: every top-level module of `src/` is in
//! exactly one row, and a module may use (`crate::…`) only modules of the rows below its own. This test reads the
//! table from docs/architecture.md and the imports from the sources, so the two cannot drift apart: a new
//! dependency that points up fails here with the file and line that adds it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The rows of the "Layers" table of docs/architecture.md, top (highest layer) first: the backticked module names
/// of each row's first cell.
fn layer_rows(page: &str) -> Vec<Vec<String>> {
    let section = page.split("\n## Layers").nth(1).expect("docs/architecture.md has a `## Layers` section");
    let section = section.split("\n## ").next().unwrap_or(section);
    section
        .lines()
        .filter(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|l| {
            let first = l.trim_start_matches('|').split('|').next().unwrap_or("");
            first.split('`').skip(1).step_by(2).map(str::to_string).collect::<Vec<_>>()
        })
        .filter(|r| !r.is_empty())
        .collect()
}

/// Top-level modules named by `crate::` paths in code (`crate::a::x`, `crate::{a::x, b}`, groups over several
/// lines included), each with the byte offset of its `crate::`.
fn crate_refs_at(text: &str) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        let at = text.len() - rest.len() + i;
        rest = &rest[i + "crate::".len()..];
        // `r2human_crate::`, `some_crate::` are not this crate.
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            // Top-level names of the brace group (nested groups belong to their parent name).
            let mut depth = 0;
            let mut name = String::new();
            let mut at_start = true;
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => at_start = true,
                    c if depth == 0 && at_start && (c.is_alphanumeric() || c == '_') => name.push(c),
                    _ if depth == 0 && at_start && !name.is_empty() => {
                        out.push((std::mem::take(&mut name), at));
                        at_start = false;
                    }
                    _ => {}
                }
            }
            if !name.is_empty() {
                out.push((name, at));
            }
        } else {
            let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            if !name.is_empty() {
                out.push((name, at));
            }
        }
    }
    out
}

/// The distinct top-level modules of [`crate_refs_at`].
fn crate_refs(text: &str) -> BTreeSet<String> {
    crate_refs_at(text).into_iter().map(|(name, _)| name).collect()
}

/// The code of a line without its `//` comment (doc comments included: they may link anywhere).
fn code(line: &str) -> &str {
    line.find("//").map_or(line, |i| &line[..i])
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level modules of `src/` (folders with a `mod.rs` and single files), without `lib` and `main`.
fn top_modules(src: &Path) -> BTreeMap<String, PathBuf> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(src).expect("src/").flatten() {
        let p = e.path();
        let name = p.file_stem().and_then(|s| s.to_str()).unwrap_or("").to_string();
        if p.is_dir() || (p.extension().is_some_and(|x| x == "rs") && name != "lib" && name != "main") {
            out.insert(name, p);
        }
    }
    out
}

#[test]
fn crate_paths_are_read_from_plain_and_grouped_uses() {
    let refs = |s: &str| crate_refs(s).into_iter().collect::<Vec<_>>();
    assert_eq!(refs("use crate::gpu::{self, Context};"), ["gpu"]);
    assert_eq!(refs("use crate::{buffer::Image, geometry::{Camera, TriMesh}, io};"), ["buffer", "geometry", "io"]);
    assert_eq!(refs("let x = crate::neural::environment(&o); crate::pipeline::f()"), ["neural", "pipeline"]);
    assert_eq!(refs("use other_crate::gpu; // crate::xr in a comment is cut by `code`"), ["xr"]);
    assert_eq!(refs(code("use other_crate::gpu; // crate::xr")), Vec::<String>::new());
    assert_eq!(refs("use crate::{\n    capture::Frame,\n    gpu::{self, Context},\n};"), ["capture", "gpu"]);
    let rows = layer_rows("x\n## Layers (y)\n\n| layer | contents |\n|---|---|\n| `cli` | a |\n| `io`, `neural` | b |\n\n## Next\n| `z` | c |\n");
    assert_eq!(rows, [vec!["cli".to_string()], vec!["io".to_string(), "neural".to_string()]]);
}

#[test]
fn lower_layers_never_import_higher_ones() {
    let page = std::fs::read_to_string(root().join("docs/architecture.md")).expect("docs/architecture.md");
    let rows = layer_rows(&page);
    let mut rank: BTreeMap<String, usize> = BTreeMap::new();
    for (i, row) in rows.iter().enumerate() {
        for m in row {
            // Rows are listed top first: a higher rank is a lower layer.
            assert!(rank.insert(m.clone(), i).is_none(), "`{m}` is in two rows of docs/architecture.md's layer table");
        }
    }
    let modules = top_modules(&root().join("src"));
    let unlisted: Vec<&String> = modules.keys().filter(|m| !rank.contains_key(*m)).collect();
    assert!(
        unlisted.is_empty(),
        "src/ modules missing from docs/architecture.md's layer table (add each to the row of its layer): {unlisted:?}"
    );
    let mut violations = Vec::new();
    for (module, path) in &modules {
        let mut files = Vec::new();
        if path.is_dir() {
            rust_files(path, &mut files);
        } else {
            files.push(path.clone());
        }
        for file in files {
            let text = std::fs::read_to_string(&file).expect("a readable source file");
            let code_only: String = text.lines().map(|l| format!("{}\n", code(l))).collect();
            for (used, at) in crate_refs_at(&code_only) {
                let (Some(&own), Some(&theirs)) = (rank.get(module), rank.get(&used)) else { continue };
                if used != *module && theirs <= own {
                    violations.push(format!(
                        "{}:{}: `{module}` uses `{used}`, which is not below it in docs/architecture.md's table",
                        file.strip_prefix(root()).unwrap_or(&file).display(),
                        code_only[..at].matches('\n').count() + 1
                    ));
                }
            }
        }
    }
    assert!(
        violations.is_empty(),
        "imports that point up or sideways (move the code down, or — if the dependency is meant and acyclic — \
         move the rows of docs/architecture.md's layer table):\n{}",
        violations.join("\n")
    );
}

/// The code of a source file that ships: the text before its `#[cfg(test)]` module (tests may print).
fn shipped_code(text: &str) -> &str {
    text.find("#[cfg(test)]\nmod tests").map_or(text, |i| &text[..i])
}

/// Lines (1-based) of `text` whose code prints to stdout or stderr directly.
fn printing_lines(text: &str) -> Vec<usize> {
    const PRINTS: [&str; 5] = ["println!(", "eprintln!(", "print!(", "eprint!(", "dbg!("];
    shipped_code(text)
        .lines()
        .enumerate()
        .filter(|(_, l)| {
            let c = code(l);
            PRINTS.iter().any(|p| {
                c.match_indices(p).any(|(i, _)| !c[..i].ends_with(|ch: char| ch == '_' || ch.is_alphanumeric()))
            })
        })
        .map(|(i, _)| i + 1)
        .collect()
}

#[test]
fn printing_is_found_outside_comments_and_tests() {
    assert_eq!(printing_lines("fn a() {\n    println!(\"x\");\n    eprintln!(\"y\");\n}\n"), [2, 3]);
    assert_eq!(printing_lines("// println!(\"in a comment\")\nfn a() { dbg!(1); }\n"), [2]);
    assert_eq!(printing_lines("fn a() { tracing::warn!(\"w\"); my_println!(1); }\n"), Vec::<usize>::new());
    assert_eq!(
        printing_lines("fn a() {}\n#[cfg(test)]\nmod tests {\n    fn b() { println!(\"ok\"); }\n}\n"),
        Vec::<usize>::new()
    );
}

/// Every Rust file under src/, sorted: its path relative to src/ and its text.
fn sources() -> Vec<(PathBuf, String)> {
    let src = root().join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    files
        .into_iter()
        .map(|file| {
            let text = std::fs::read_to_string(&file).expect("a readable source file");
            (file.strip_prefix(&src).unwrap_or(&file).to_path_buf(), text)
        })
        .collect()
}

/// One warning channel: below `cli`, the library never prints. Warnings and progress notes go through `tracing`
/// (the CLI's subscriber writes them to stderr); results go back to the CLI, which prints the summaries it means
/// to print and its error sentence.
#[test]
fn only_the_cli_prints() {
    let mut found = Vec::new();
    for (rel, text) in sources() {
        if rel.starts_with("cli") || rel == Path::new("main.rs") {
            continue;
        }
        for line in printing_lines(&text) {
            found.push(format!("src/{}:{line}", rel.display()));
        }
    }
    assert!(
        found.is_empty(),
        "library code prints (warnings: `tracing::warn!`; results: return them to `cli`, which prints):\n{}",
        found.join("\n")
    );
}

/// Lines (1-based) of `text`'s shipped code that name a `Result` whose error type (its last top-level generic
/// argument) is `String`: `-> Result<T, String>`, `Result<(A, B), String>` in a closure or type alias,
/// `OnceLock<Result<T, String>>`. `io::Result<String>` (one argument) and `Result<String, E>` are not.
fn string_error_lines(text: &str) -> Vec<usize> {
    let mut out = Vec::new();
    for (i, line) in shipped_code(text).lines().enumerate() {
        let c = code(line);
        let found = c.match_indices("Result<").any(|(at, _)| {
            // The generic arguments, split at the commas of the top level (not inside `<>`, `()` or `[]`).
            let mut args = vec![String::new()];
            let mut depth = 0usize;
            let mut prev = ' ';
            for ch in c[at + "Result<".len()..].chars() {
                match ch {
                    '<' | '(' | '[' => depth += 1,
                    '>' if prev == '-' => {} // the arrow of a `Fn(..) -> T` bound
                    '>' | ')' | ']' if depth == 0 => break,
                    '>' | ')' | ']' => depth -= 1,
                    ',' if depth == 0 => {
                        args.push(String::new());
                        prev = ch;
                        continue;
                    }
                    _ => {}
                }
                if let Some(last) = args.last_mut() {
                    last.push(ch);
                }
                prev = ch;
            }
            let error = args.last().map(|a| a.trim()).unwrap_or("");
            args.len() > 1 && (error == "String" || error == "std::string::String")
        });
        if found {
            out.push(i + 1);
        }
    }
    out
}

#[test]
fn string_errors_are_found_in_signatures_closures_and_fields() {
    let text = "fn a(s: &str) -> Result<u32, String> {\n\
                fn b() -> std::io::Result<String> {\n\
                fn c() -> Result<String, MyError> {\n\
                type Opener = Box<dyn FnMut(u32) -> Result<Box<dyn Cam>, String> + Send>;\n\
                let f = |v: &View| -> Result<(Vec<u8>, usize), String> { v };\n\
                static CELL: OnceLock<Result<Model, std::string::String>> = OnceLock::new();\n\
                // fn d() -> Result<(), String> in a comment\n\
                fn e() -> Result<HashMap<String, String>, Error> {\n\
                #[cfg(test)]\nmod tests {\n    fn t() -> Result<(), String> {}\n}\n";
    assert_eq!(string_error_lines(text), [1, 4, 5, 6]);
}

/// The `Result<_, String>`s that stay, each with its reason: (file under src/, text of the line, why).
const STRING_ERRORS_ALLOWED: [(&str, &str, &str); 6] = [
    (
        "cli/data.rs",
        "pub fn parse_framing_choice(s: &str)",
        "a clap value parser at the edge: clap prints the String as the argument's error",
    ),
    ("cli/data.rs", "pub fn parse_framing(s: &str)", "a clap value parser at the edge, as above"),
    (
        "xr/check.rs",
        "pub system: Result<SystemSummary, String>",
        "a report field: why there is no headset, as the sentence `r2human xr --check` prints",
    ),
    (
        "app/live.rs",
        "pub result: Result<PathBuf, String>",
        "a report field of `render --video` (the app edge): the PNG written or why the frame was skipped",
    ),
    (
        "body/model.rs",
        "static CELL: OnceLock<Result<BodyModel, String>>",
        "a process-wide cache of a load failure: errors are not Clone, so the message is kept and each call gets \
         a fresh `BodyError::Asset`",
    ),
    ("synth/mod.rs", "static CELL: OnceLock<Result<SynthAssets, String>>", "the same cache for `SynthError::Asset`"),
];

/// One error style: below the edge, failures are typed (thiserror enums with the file and the cause chain), not
/// `String`s. The few that stay are listed with their reason in [`STRING_ERRORS_ALLOWED`]; an entry that no
/// longer matches anything fails too, so the list cannot go stale.
#[test]
fn errors_are_typed_not_strings() {
    let mut found = Vec::new();
    let mut used = [false; STRING_ERRORS_ALLOWED.len()];
    for (rel, text) in sources() {
        let lines: Vec<&str> = text.lines().collect();
        for n in string_error_lines(&text) {
            let allowed = STRING_ERRORS_ALLOWED
                .iter()
                .position(|(f, line, _)| rel == Path::new(f) && lines[n - 1].contains(line));
            match allowed {
                Some(k) => used[k] = true,
                None => found.push(format!("src/{}:{n}: {}", rel.display(), lines[n - 1].trim())),
            }
        }
    }
    assert!(
        found.is_empty(),
        "`Result<_, String>` below the edge: return the module's thiserror enum (keep the file name and the cause \
         as `#[source]`), or add the line to STRING_ERRORS_ALLOWED with the reason it must stay:\n{}",
        found.join("\n")
    );
    let stale: Vec<String> = STRING_ERRORS_ALLOWED
        .iter()
        .zip(used)
        .filter(|(_, u)| !u)
        .map(|((f, line, _), _)| format!("src/{f}: {line}"))
        .collect();
    assert!(stale.is_empty(), "STRING_ERRORS_ALLOWED lists lines that are gone; remove them:\n{}", stale.join("\n"));
}

/// Lines (1-based) of `text` where a `.map_err(..)` turns the error into text with `.to_string()` (the argument
/// is read up to its closing parenthesis, so a closure over several lines counts once, on its first line).
fn stringified_error_lines(text: &str) -> Vec<usize> {
    let code_only: String = shipped_code(text).lines().map(|l| format!("{}\n", code(l))).collect();
    let mut out = Vec::new();
    for (at, _) in code_only.match_indices(".map_err(") {
        let arg = &code_only[at + ".map_err(".len()..];
        let mut depth = 1usize;
        let end = arg
            .char_indices()
            .find(|&(_, ch)| {
                match ch {
                    '(' => depth += 1,
                    ')' => depth -= 1,
                    _ => {}
                }
                depth == 0
            })
            .map_or(arg.len(), |(i, _)| i);
        if arg[..end].contains(".to_string()") {
            out.push(code_only[..at].matches('\n').count() + 1);
        }
    }
    out
}

/// Errors keep their cause: below `cli`, a `map_err` that wraps one of the crate's own errors carries it as the
/// new variant's `#[source]` (`PipelineError::FofNetLoad`, `CaptureError::ModelLoad`, ...), never as its
/// `.to_string()`. An outside library's error may stay text; [`CAUSE_AS_TEXT_ALLOWED`] counts those sites per
/// file with the library they wrap, so a new `map_err(|e| X(e.to_string()))` anywhere fails here until it is
/// made a `#[source]` or listed with its reason (and a removed one fails until its count is lowered).
#[test]
fn errors_keep_their_cause() {
    let mut counts: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (rel, text) in sources() {
        if rel.starts_with("cli") || rel == Path::new("main.rs") {
            continue;
        }
        let lines = stringified_error_lines(&text);
        if !lines.is_empty() {
            counts.insert(rel.to_string_lossy().replace('\\', "/"), lines);
        }
    }
    let mut wrong = Vec::new();
    for (file, lines) in &counts {
        let allowed = CAUSE_AS_TEXT_ALLOWED.iter().find(|(f, _, _)| f == file).map_or(0, |(_, n, _)| *n);
        if lines.len() != allowed {
            wrong.push(format!("src/{file}: {} sites (lines {lines:?}), {allowed} allowed", lines.len()));
        }
    }
    for (file, n, _) in CAUSE_AS_TEXT_ALLOWED {
        if !counts.contains_key(file) {
            wrong.push(format!("src/{file}: 0 sites, {n} allowed (lower the count)"));
        }
    }
    assert!(
        wrong.is_empty(),
        "`.map_err(|e| ...(e.to_string()))` below the edge: wrap the crate's own errors as `#[source]` (a variant \
         with the same words), or update CAUSE_AS_TEXT_ALLOWED with the outside library and why it stays text:\n{}",
        wrong.join("\n")
    );
}

/// The scan behind [`errors_keep_their_cause`] finds one-line and multi-line wraps, and not a `#[source]` wrap,
/// a comment or test code.
#[test]
fn stringified_errors_are_found() {
    let text = "fn a() {\n    f().map_err(|e| X(e.to_string()))?;\n    g().map_err(|e| Y {\n        reason: e.to_string(),\n    })?;\n    h().map_err(|source| Z { source })?;\n    // k().map_err(|e| X(e.to_string()))\n}\n#[cfg(test)]\nmod tests {\n    f().map_err(|e| e.to_string());\n}\n";
    assert_eq!(stringified_error_lines(text), vec![2, 3]);
}

/// Files whose `map_err(.. .to_string())` sites wrap only errors from outside the crate (or keep a message for a
/// stated reason), how many there are, and why each stays text.
const CAUSE_AS_TEXT_ALLOWED: [(&str, usize, &str); 21] = [
    ("app/live.rs", 2, "std::io::Error of a thread spawn and of creating the output folder (std, not the crate's)"),
    ("body/base.rs", 1, "serde_json (the embedded vertex groups)"),
    ("body/model.rs", 1, "the load-once cache keeps the message (errors are not Clone; see STRING_ERRORS_ALLOWED)"),
    ("body/morph.rs", 2, "zip (the MakeHuman targets archive)"),
    (
        "body/mod.rs",
        4,
        "ndarray's ShapeError and ort (tensor, run, extract): run_image_network, the pose and face networks",
    ),
    ("body/rig.rs", 3, "serde_json (rig, weights) and a path as text"),
    ("capture/mod.rs", 1, "std::io::Error of `metadata`"),
    ("capture/onnx.rs", 3, "ort (tensor, run, extract)"),
    ("capture/sequence.rs", 1, "std::io::Error of `read_dir`"),
    ("capture/video.rs", 2, "std::io::Error of spawning ffprobe/ffmpeg, matched on its kind"),
    ("eval/runner.rs", 7, "plotters: its DrawingAreaErrorKind is generic over the backend's error"),
    ("eval/turn.rs", 6, "plotters: its DrawingAreaErrorKind is generic over the backend's error (the turn plot)"),
    ("gpu/context.rs", 1, "ash's LoadingError (`Entry::load`)"),
    ("io/environment.rs", 2, "image's ImageError (the HDR decoder)"),
    ("io/mesh_io.rs", 1, "serde_json (the glTF JSON chunk)"),
    ("io/ply.rs", 1, "ply-rs (the header)"),
    (
        "neural/nets.rs",
        1,
        "BadFofInputs: a private message type whose whole content is the words the metadata error shows",
    ),
    (
        "neural/provider.rs",
        11,
        "ort (library load, session builder, execution providers) and std::io::Error of canonicalize",
    ),
    ("synth/mod.rs", 1, "the load-once cache, as body/model.rs"),
    ("window/mirror.rs", 3, "winit/raw-window-handle's HandleError"),
    ("xr/check.rs", 1, "a report field: the sentence `r2human xr --check` prints (see STRING_ERRORS_ALLOWED)"),
];

/// Lines (1-based) of `text` that open an `unsafe` block or `unsafe impl` without a `// SAFETY:` comment: on the
/// same line, or in the comment lines directly above the statement that holds it (a statement may span lines; a
/// blank line or the end of the previous statement ends the search).
fn unexplained_unsafe(text: &str) -> Vec<usize> {
    let lines: Vec<&str> = text.lines().collect();
    let opens_unsafe = |l: &str| {
        let c = code(l);
        c.contains("unsafe {") || c.trim_end().ends_with("unsafe") || c.contains("unsafe impl")
    };
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        if !opens_unsafe(line) || line.contains("SAFETY:") {
            continue;
        }
        let mut explained = false;
        for above in lines[..i].iter().rev() {
            let t = above.trim();
            if t.starts_with("//") {
                if t.contains("SAFETY:") {
                    explained = true;
                    break;
                }
                continue;
            }
            let c = code(t).trim_end();
            // A blank line, an attribute-free block boundary or the end of the previous statement: stop.
            if c.is_empty() || c.ends_with(';') || c.ends_with('{') || c.ends_with('}') || c.ends_with(',') {
                break;
            }
        }
        if !explained {
            out.push(i + 1);
        }
    }
    out
}

/// Lines (1-based) of `text` that declare an `unsafe fn` without a `# Safety` section in the doc comment directly
/// above it (the caller's contract).
fn undocumented_unsafe_fns(text: &str) -> Vec<usize> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let c = code(line);
        if !(c.contains("unsafe fn ") || (c.contains("unsafe extern") && c.contains(" fn "))) {
            continue;
        }
        let doc = lines[..i].iter().rev().map(|l| l.trim()).take_while(|t| t.starts_with("///") || t.starts_with("#["));
        if !doc.into_iter().any(|t| t.starts_with("/// # Safety")) {
            out.push(i + 1);
        }
    }
    out
}

#[test]
fn unsafe_lines_are_found_with_and_without_their_reason() {
    let documented = "/// Does it.\n///\n/// # Safety\n/// `p` is valid.\n#[inline]\nunsafe fn f(p: *const u8) {}\n";
    assert_eq!(undocumented_unsafe_fns(documented), Vec::<usize>::new());
    assert_eq!(undocumented_unsafe_fns("/// Does it.\nunsafe extern \"system\" fn cb() {}\n"), [2]);
    let ok = "fn a() {\n    // SAFETY: the handle is alive.\n    unsafe { f() };\n}\n";
    assert_eq!(unexplained_unsafe(ok), Vec::<usize>::new());
    let spanning = "fn a() {\n    // SAFETY: the pool outlives the buffer.\n    let x =\n        unsafe { f() };\n}\n";
    assert_eq!(unexplained_unsafe(spanning), Vec::<usize>::new());
    let bare = "fn a() {\n    let y = 1;\n    unsafe { f() };\n    // SAFETY: only for the next one.\n    unsafe { g() };\n}\n";
    assert_eq!(unexplained_unsafe(bare), [3]);
    let far = "// SAFETY: too far above.\nlet a = 1;\nunsafe { h() };\nunsafe impl Send for X {}\n";
    assert_eq!(unexplained_unsafe(far), [3, 4]);
    assert_eq!(unexplained_unsafe("let r = unsafe { f() }; // SAFETY: on the same line.\n"), Vec::<usize>::new());
}

/// Every `unsafe` block and `unsafe impl` in src/ says why it is sound (`// SAFETY: …` naming the invariant: the
/// handle's lifetime, the synchronisation, the bounds), and every `unsafe fn` states its caller's contract.
#[test]
fn every_unsafe_says_why_it_is_sound() {
    let mut found = Vec::new();
    for (rel, text) in sources() {
        let rel = format!("src/{}", rel.display());
        for line in unexplained_unsafe(&text) {
            found.push(format!("{rel}:{line}: unsafe without a `// SAFETY:` comment above it"));
        }
        for line in undocumented_unsafe_fns(&text) {
            found.push(format!("{rel}:{line}: unsafe fn without a `# Safety` section in its doc comment"));
        }
    }
    assert!(found.is_empty(), "{} unexplained unsafe:\n{}", found.len(), found.join("\n"));
}
