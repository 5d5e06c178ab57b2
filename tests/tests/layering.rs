//! Layers import in one direction: no two source files of a crate import each other, directly
//! or through others. A cycle makes a module impossible to read, test or move on its own, and
//! it creeps in one convenient `use` at a time, so the tree is checked as a whole here.
//!
//! Each `.rs` file under a crate's `src/` is a node (`a/mod.rs` is the module `a`); a path
//! `crate::x::y` or `super::y` in its code (comments and its `#[cfg(test)] mod tests` block left
//! out: a test may reach anywhere) is an edge to the longest module prefix that is a file. The
//! strongly connected components with more than one file are the cycles.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// The crates whose files are checked, relative to the workspace root.
const CRATE_SOURCES: &[&str] = &[
    "kinematics-core/src",
    "host-sim/src",
    "firmware/src",
    "firmware/controller/src",
    "firmware/g474-plan/src",
    "firmware/link-protocol/src",
    "firmware/cosim-wire/src",
];

type Module = Vec<String>;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// Every `.rs` file below `dir`, except test-only files (`tests.rs`, `tests/` directories).
fn source_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if p.is_dir() {
            if name != "tests" {
                source_files(&p, out);
            }
        } else if name.ends_with(".rs") && name != "tests.rs" {
            out.push(p);
        }
    }
}

/// The module path of a file relative to its crate's `src/`.
fn module_of(src: &Path, file: &Path) -> Module {
    let rel = file.strip_prefix(src).expect("file under src");
    let mut parts: Module = rel
        .with_extension("")
        .iter()
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The file's code without comments and without its inline test module.
fn code_of(text: &str) -> String {
    let cut = text
        .find("#[cfg(test)]\nmod tests")
        .or_else(|| text.find("#[cfg(test)]\npub(crate) mod tests"))
        .unwrap_or(text.len());
    text[..cut]
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The paths `crate::a::b...` and `super::a...` in `code`, resolved against `module`, as the
/// segment lists they name (import groups `{...}` contribute their common prefix).
fn referenced_paths(code: &str, module: &Module) -> Vec<Module> {
    let mut found = Vec::new();
    let bytes = code.as_bytes();
    for anchor in ["crate::", "super::"] {
        let mut from = 0;
        while let Some(at) = code[from..].find(anchor) {
            let start = from + at;
            from = start + anchor.len();
            // `crate::` must start an identifier path (not `my_crate::`).
            if start > 0 && (bytes[start - 1].is_ascii_alphanumeric() || bytes[start - 1] == b'_') {
                continue;
            }
            let mut base: Module = if anchor == "crate::" {
                Vec::new()
            } else {
                // `super` of `a/b.rs` (module `a::b`) is `a`; of `a/mod.rs` (module `a`), `a`'s
                // parent: the module's parent either way.
                let mut m = module.clone();
                m.pop();
                m
            };
            let rest = &code[from..];
            for seg in rest.split("::") {
                let ident: String = seg
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if ident.is_empty() || ident == "super" {
                    break;
                }
                base.push(ident.clone());
                if ident.len() != seg.len() {
                    break;
                }
            }
            found.push(base);
        }
    }
    found
}

/// The strongly connected components of `edges` with more than one node (Tarjan).
fn cycles(edges: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    struct State<'a> {
        edges: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: BTreeMap<&'a Module, usize>,
        low: BTreeMap<&'a Module, usize>,
        stack: Vec<&'a Module>,
        on_stack: BTreeSet<&'a Module>,
        out: Vec<Vec<Module>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a Module) {
        let i = s.index.len();
        s.index.insert(v, i);
        s.low.insert(v, i);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.edges.get(v).into_iter().flatten() {
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on_stack.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                s.out.push(comp);
            }
        }
    }
    let mut s = State {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

/// The import edges between the files of one crate (its `src/`, binaries apart).
fn file_graph(src: &Path) -> BTreeMap<Module, BTreeSet<Module>> {
    let mut files = Vec::new();
    source_files(src, &mut files);
    let modules: BTreeMap<Module, &PathBuf> =
        files.iter().map(|f| (module_of(src, f), f)).collect();
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (module, file) in &modules {
        // A binary's files (`src/bin/...`) are a crate of their own: not this graph's.
        if module.first().map(String::as_str) == Some("bin") {
            continue;
        }
        let text = fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let targets = edges.entry(module.clone()).or_default();
        for path in referenced_paths(&code_of(&text), module) {
            // The longest prefix of the path that is a file of this crate.
            let target = (1..=path.len())
                .rev()
                .map(|k| path[..k].to_vec())
                .find(|p| modules.contains_key(p));
            if let Some(t) = target {
                if &t != module {
                    targets.insert(t);
                }
            }
        }
    }
    edges
}

#[test]
fn no_two_source_files_import_each_other() {
    let root = workspace_root();
    let mut found = Vec::new();
    for dir in CRATE_SOURCES {
        let src = root.join(dir);
        assert!(src.is_dir(), "{} is not a directory", src.display());
        for comp in cycles(&file_graph(&src)) {
            let names: Vec<String> = comp
                .iter()
                .map(|m| {
                    if m.is_empty() {
                        "lib".into()
                    } else {
                        m.join("/")
                    }
                })
                .collect();
            found.push(format!("{dir}: {}", names.join(" <-> ")));
        }
    }
    assert!(
        found.is_empty(),
        "files that import each other (move what both need into a module both import):\n{}",
        found.join("\n")
    );
}

#[test]
fn the_check_finds_a_cycle_it_is_given() {
    let a: Module = vec!["a".into()];
    let b: Module = vec!["b".into()];
    let c: Module = vec!["c".into()];
    let mut edges = BTreeMap::new();
    edges.insert(a.clone(), BTreeSet::from([b.clone()]));
    edges.insert(b.clone(), BTreeSet::from([a.clone(), c.clone()]));
    edges.insert(c.clone(), BTreeSet::new());
    assert_eq!(cycles(&edges).len(), 1);
    edges.get_mut(&b).unwrap().remove(&a);
    assert!(cycles(&edges).is_empty());
    // Paths resolve against the file's module: `super::x` in `d/e.rs` is `d::x`.
    let paths = referenced_paths("use super::x::Y;", &vec!["d".into(), "e".into()]);
    assert_eq!(paths, vec![vec!["d".to_string(), "x".into(), "Y".into()]]);
    let paths = referenced_paths("use crate::f::{g, h};", &vec![]);
    assert_eq!(paths, vec![vec!["f".to_string()]]);
}
