//! The source layout (ARCHITECTURE.md, "Layout"): the files of each crate import each other
//! without cycles, every `mod.rs` and `lib.rs` is a code map, and production functions are short
//! enough to read at once. These tests read the sources; they start no process.
//!
//! A file's imports are the `crate::…` and `super::…` paths in its code (comments and the
//! `#[cfg(test)]` module at its bottom left out). A path names the file of the longest module
//! prefix it has; a name that a `mod.rs` re-exports (`pub use child::Name`) names the child's
//! file, since the code map only points at it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The crates' source folders, from the workspace root.
const CRATES: [&str; 5] = [
    "src",
    "proto/src",
    "robot-agent/src",
    "world-server/src",
    "netem/src",
];

/// Import cycles not broken yet (issue #36 is open on them): the test fails on any other cycle,
/// and on one of these once it is gone (so the list only shrinks).
const KNOWN_CYCLES: &[&str] = &[];

/// Production functions longer than [`MAX_FN_LINES`] not split yet (issue #36 is open on them):
/// the test fails on any other long function, and on one of these once it is short.
const LONG_FUNCTIONS: &[&str] = &[];

/// The longest production function, in lines from its signature to its closing brace.
const MAX_FN_LINES: usize = 80;

/// The most lines of code (not blank, not comments) a `mod.rs` or `lib.rs` may have.
const MAX_MAP_LINES: usize = 60;

type Module = Vec<String>;

struct Source {
    file: PathBuf,
    /// The code before the test module, comment lines blanked (line numbers kept).
    code: String,
    /// `mod.rs`, `lib.rs` or `main.rs`: the module is the folder.
    is_root: bool,
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The code of a file before its `#[cfg(test)]` module, with comment lines blanked.
fn production(text: &str) -> String {
    let end = text
        .find("#[cfg(test)]\nmod tests")
        .or_else(|| text.find("#[cfg(test)]\nmod "))
        .unwrap_or(text.len());
    text[..end]
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("//") {
                ""
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn sources(src: &Path) -> BTreeMap<Module, Source> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut out = BTreeMap::new();
    for file in files {
        let rel = file.strip_prefix(src).expect("under src");
        let mut module: Module = rel
            .with_extension("")
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        let is_root = matches!(
            module.last().map(String::as_str),
            Some("mod" | "lib" | "main")
        );
        if is_root {
            module.pop();
        }
        // main.rs and lib.rs are two crates' roots; only lib.rs is the library's.
        if rel == Path::new("main.rs") {
            module = vec!["<main>".into()];
        }
        let text = std::fs::read_to_string(&file).expect("readable source");
        out.insert(
            module,
            Source {
                code: production(&text),
                file,
                is_root,
            },
        );
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The identifiers of a path starting at `s`: `a::b::c` → [a, b, c]; stops before `{` or `*`.
fn path_at(s: &str) -> (Vec<String>, &str) {
    let mut segs = Vec::new();
    let mut rest = s;
    loop {
        let n = rest.find(|c: char| !is_ident(c)).unwrap_or(rest.len());
        if n == 0 {
            break;
        }
        segs.push(rest[..n].to_string());
        rest = &rest[n..];
        match rest.strip_prefix("::") {
            Some(r) if r.starts_with(|c: char| is_ident(c)) => rest = r,
            _ => break,
        }
    }
    (segs, rest)
}

/// The top-level items of a `{…}` group starting after its `{`: each item's leading path.
fn group_items(s: &str) -> Vec<Vec<String>> {
    let mut items = Vec::new();
    let mut depth = 0usize;
    let mut start = 0usize;
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => {
                items.push(&s[start..i]);
                break;
            }
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&s[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    items
        .into_iter()
        .map(|it| path_at(it.trim_start()).0)
        .filter(|p| !p.is_empty())
        .collect()
}

/// Every path after `prefix::` in `code`, groups expanded one level.
fn paths_after(code: &str, prefix: &str) -> Vec<Vec<String>> {
    let needle = format!("{prefix}::");
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(i) = code[at..].find(&needle) {
        let start = at + i;
        at = start + needle.len();
        if start > 0 && code[..start].ends_with(|c: char| is_ident(c) || c == ':') {
            continue;
        }
        let rest = &code[at..];
        if let Some(group) = rest.strip_prefix('{') {
            out.extend(group_items(group));
        } else {
            let (segs, after) = path_at(rest);
            if let Some(group) = after.strip_prefix("::{") {
                for item in group_items(group) {
                    out.push(segs.iter().cloned().chain(item).collect());
                }
            } else if !segs.is_empty() {
                out.push(segs);
            }
        }
    }
    out
}

/// `pub use child::{A, B}` in a code map: name → the child module it comes from.
fn reexports(module: &Module, s: &Source) -> BTreeMap<String, Module> {
    let mut out = BTreeMap::new();
    if !s.is_root {
        return out;
    }
    for stmt in s.code.split(';') {
        let Some(rest) = stmt.trim_start().strip_prefix("pub use ") else {
            continue;
        };
        let rest = rest.trim_start_matches("self::");
        let (segs, after) = path_at(rest);
        let Some(child) = segs.first() else { continue };
        let child: Module = module.iter().cloned().chain([child.clone()]).collect();
        if let Some(group) = after.strip_prefix("::{") {
            for item in group_items(group) {
                if let Some(name) = item.last() {
                    out.insert(name.clone(), child.clone());
                }
            }
        } else if let Some(name) = segs.last() {
            out.insert(name.clone(), child);
        }
    }
    out
}

/// The file a path (from the crate root) names.
fn resolve(
    path: &[String],
    files: &BTreeMap<Module, Source>,
    maps: &BTreeMap<Module, BTreeMap<String, Module>>,
) -> Option<Module> {
    let mut k = path.len();
    while k > 0 && !files.contains_key(&path[..k]) {
        k -= 1;
    }
    let mut target: Module = path[..k].to_vec();
    if let Some(name) = path.get(k) {
        if let Some(child) = maps.get(&target).and_then(|m| m.get(name)) {
            target = child.clone();
        }
    }
    (!target.is_empty()).then_some(target)
}

/// The file → files graph of one crate: edges from each file to the files it imports.
fn imports(src: &Path) -> BTreeMap<Module, BTreeSet<Module>> {
    let files = sources(src);
    let maps: BTreeMap<Module, BTreeMap<String, Module>> = files
        .iter()
        .map(|(m, s)| (m.clone(), reexports(m, s)))
        .collect();
    let mut graph = BTreeMap::new();
    for (module, s) in &files {
        let mut code = s.code.clone();
        if s.is_root {
            // A code map's `pub use` lines point at children; they are not imports.
            code = code
                .split(';')
                .filter(|st| !st.trim_start().starts_with("pub use "))
                .collect::<Vec<_>>()
                .join(";");
        }
        let parent: Module = if s.is_root {
            module.clone()
        } else {
            module[..module.len().saturating_sub(1)].to_vec()
        };
        let mut to = BTreeSet::new();
        let crate_paths = paths_after(&code, "crate");
        let super_paths = paths_after(&code, "super").into_iter().map(|p| {
            let base = &parent[..parent.len().saturating_sub(usize::from(s.is_root))];
            base.iter().cloned().chain(p).collect::<Vec<_>>()
        });
        for path in crate_paths.into_iter().chain(super_paths) {
            if let Some(t) = resolve(&path, &files, &maps) {
                if &t != module {
                    to.insert(t);
                }
            }
        }
        graph.insert(module.clone(), to);
    }
    graph
}

/// The cycles of a graph: its strongly connected components of more than one node.
fn cycles(graph: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    // Kosaraju: finish order on the graph, then components on the reversed graph.
    fn visit<'a>(
        n: &'a Module,
        g: &'a BTreeMap<Module, BTreeSet<Module>>,
        seen: &mut BTreeSet<&'a Module>,
        out: &mut Vec<&'a Module>,
    ) {
        if !seen.insert(n) {
            return;
        }
        for m in g.get(n).into_iter().flatten() {
            visit(m, g, seen, out);
        }
        out.push(n);
    }
    let mut order = Vec::new();
    let mut seen = BTreeSet::new();
    for n in graph.keys() {
        visit(n, graph, &mut seen, &mut order);
    }
    let mut reversed: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (a, tos) in graph {
        for b in tos {
            reversed.entry(b.clone()).or_default().insert(a.clone());
        }
    }
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    for n in order.into_iter().rev() {
        let mut comp = Vec::new();
        visit(n, &reversed, &mut seen, &mut comp);
        if comp.len() > 1 {
            out.push(comp.into_iter().cloned().collect());
        }
    }
    out
}

#[test]
fn no_file_of_a_crate_imports_a_file_that_imports_it_back() {
    let mut found = Vec::new();
    for krate in CRATES {
        for cycle in cycles(&imports(&root().join(krate))) {
            let mut names: Vec<String> = cycle.iter().map(|m| m.join("::")).collect();
            names.sort();
            found.push(format!("{krate}: {}", names.join(" ↔ ")));
        }
    }
    let new: Vec<&String> = found
        .iter()
        .filter(|c| !KNOWN_CYCLES.contains(&c.as_str()))
        .collect();
    assert!(new.is_empty(), "import cycles: {new:#?}");
    let gone: Vec<&&str> = KNOWN_CYCLES
        .iter()
        .filter(|k| !found.iter().any(|c| c == *k))
        .collect();
    assert!(gone.is_empty(), "listed in KNOWN_CYCLES but gone: {gone:?}");
}

#[test]
fn the_cycle_check_finds_a_cycle_between_two_files() {
    let m = |s: &str| vec![s.to_string()];
    let graph: BTreeMap<Module, BTreeSet<Module>> = [
        (m("a"), [m("b")].into()),
        (m("b"), [m("a"), m("c")].into()),
        (m("c"), BTreeSet::new()),
    ]
    .into();
    let found = cycles(&graph);
    assert_eq!(found.len(), 1);
    assert_eq!(
        found[0].iter().collect::<BTreeSet<_>>(),
        [&m("a"), &m("b")].into()
    );
    // And the parser sees both forms of import.
    let code = "use crate::{a::X, b};\nfn f() { crate::c::d::g(); super::e::h() }";
    assert_eq!(
        paths_after(code, "crate"),
        [vec!["a", "X"], vec!["b"], vec!["c", "d", "g"]]
            .map(|p| p.into_iter().map(String::from).collect::<Vec<_>>())
            .to_vec()
    );
    assert_eq!(
        paths_after(code, "super"),
        [vec!["e".to_string(), "h".into()]]
    );
}

#[test]
fn every_mod_rs_and_lib_rs_is_a_code_map() {
    let mut found = Vec::new();
    for krate in CRATES {
        for s in sources(&root().join(krate)).values() {
            let name = s.file.file_name().and_then(|n| n.to_str());
            if !matches!(name, Some("mod.rs" | "lib.rs")) {
                continue;
            }
            let code: Vec<&str> = s.code.lines().filter(|l| !l.trim().is_empty()).collect();
            let logic = code.iter().any(|l| {
                let l = l.trim_start();
                l.starts_with("fn ")
                    || l.starts_with("pub fn ")
                    || l.starts_with("impl")
                    || l.starts_with("pub struct ")
                    || l.starts_with("pub enum ")
            });
            if code.len() > MAX_MAP_LINES || logic {
                found.push(format!(
                    "{}: {} lines of code{}",
                    s.file.display(),
                    code.len(),
                    if logic { ", with logic" } else { "" }
                ));
            }
        }
    }
    assert!(found.is_empty(), "not code maps:\n{}", found.join("\n"));
}

/// `(name, first line, lines)` of every function in `code` (a function inside another counts
/// once, as part of it).
fn functions(code: &str) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = code.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let t = lines[i].trim_start();
        let sig = t
            .trim_start_matches("pub(crate) ")
            .trim_start_matches("pub(super) ")
            .trim_start_matches("pub ")
            .trim_start_matches("const ")
            .trim_start_matches("async ")
            .trim_start_matches("unsafe ");
        let Some(rest) = sig.strip_prefix("fn ") else {
            i += 1;
            continue;
        };
        let name: String = rest.chars().take_while(|&c| is_ident(c)).collect();
        // The body: from the first `{` after the signature to its match.
        let mut depth = 0i32;
        let mut opened = false;
        let mut j = i;
        'body: while j < lines.len() {
            for c in lines[j].chars() {
                match c {
                    '{' => {
                        depth += 1;
                        opened = true;
                    }
                    '}' => depth -= 1,
                    ';' if !opened => break 'body,
                    _ => {}
                }
                if opened && depth == 0 {
                    break 'body;
                }
            }
            j += 1;
        }
        if opened {
            out.push((name, i + 1, j - i + 1));
            i = j + 1;
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn production_functions_are_short_enough_to_read_at_once() {
    let mut found = Vec::new();
    let mut allowed_seen = BTreeSet::new();
    for krate in CRATES {
        for s in sources(&root().join(krate)).values() {
            let file = s.file.strip_prefix(root()).unwrap_or(&s.file);
            for (name, line, len) in functions(&s.code) {
                let key = format!("{}::{name}", file.display());
                if len <= MAX_FN_LINES {
                    continue;
                }
                if LONG_FUNCTIONS.contains(&key.as_str()) {
                    allowed_seen.insert(key);
                    continue;
                }
                found.push(format!("{key} (line {line}): {len} lines"));
            }
        }
    }
    assert!(
        found.is_empty(),
        "functions over {MAX_FN_LINES} lines:\n{}",
        found.join("\n")
    );
    let stale: Vec<_> = LONG_FUNCTIONS
        .iter()
        .filter(|k| !allowed_seen.contains(**k))
        .collect();
    assert!(stale.is_empty(), "listed but no longer long: {stale:?}");
}
