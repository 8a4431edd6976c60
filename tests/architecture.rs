//! The dependency rules of docs/architecture.md, checked on the source: every `crate::`,
//! `super::` and `self::` path in `src/` is resolved to the file it names, and a path
//! that breaks a rule fails this test with its file and line. The same resolution finds
//! circles of files that import each other; the circles that exist today are listed
//! below (docs/architecture.md says which), so that a new one fails and a removed one
//! must leave the list.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One rule: files under `from` (a path prefix in `src/`, e.g. "src/nn/") must not use
/// the modules in `to` (top-level modules of the crate), for the reason given.
struct Rule {
    from: &'static [&'static str],
    except: &'static [&'static str],
    to: &'static [&'static str],
    why: &'static str,
}

const RULES: &[Rule] = &[
    Rule {
        from: &["src/engine/", "src/nn/"],
        except: &[],
        to: &["avatar"],
        why: "no skeleton at play time: the live loop and the model never import the teacher",
    },
    Rule {
        from: &["src/gpu/"],
        except: &[],
        to: &[
            "nn", "splat", "engine", "render", "app", "avatar", "autorig", "dataset", "posmap",
            "headless", "bench", "make", "cli",
        ],
        why: "src/gpu knows no model, no splat and no window",
    },
    Rule {
        from: &["src/nn/"],
        except: &[],
        to: &["splat"],
        why: "nn and splat meet only in src/engine",
    },
    Rule {
        from: &["src/splat/"],
        except: &[],
        to: &["nn"],
        why: "nn and splat meet only in src/engine",
    },
    Rule {
        from: &["src/splat/"],
        except: &[],
        to: &["render"],
        why: "render draws splats over the scene; splat knows no render target or camera",
    },
    Rule {
        from: &["src/"],
        except: &["src/app/", "src/cli/", "src/main.rs", "src/lib.rs"],
        to: &["app"],
        why: "nothing in the core imports the window (src/app); only the command line does",
    },
];

/// Circles of files that import each other and are allowed for now (each as its sorted
/// files joined by " <-> "): none. The test fails on any circle not listed, and on a
/// listed one that no longer exists, so that this list can only shrink.
const KNOWN_CIRCLES: &[&str] = &[];

/// The most lines a source file in `src/` may have: past it a file holds more than one
/// thing to find one's way in.
const MAX_LINES: usize = 800;

/// Files allowed over [`MAX_LINES`] for now: none. The test fails on any other, and on a
/// listed one that is no longer over (the list can only shrink).
const KNOWN_LONG_FILES: &[&str] = &[];

/// A use of another module: the line it is on, the module path it names (crate-rooted),
/// and whether it is a `pub use` (a re-export).
#[derive(Debug, Clone, PartialEq)]
struct Use {
    line: usize,
    path: Vec<String>,
    reexport: bool,
}

/// The module path of a source file: src/nn/ops.rs → [nn, ops]; src/nn/mod.rs → [nn].
fn module_of(file: &Path) -> Vec<String> {
    let rel = file.strip_prefix("src").unwrap_or(file);
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap_or_default();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" && stem != "main" {
        parts.push(stem.to_string());
    }
    parts
}

/// Expands a `use` tree (the text between `use` and `;`) into full paths:
/// `a::{b, c::{d, e}}` → a::b, a::c::d, a::c::e.
fn expand_use(tree: &str) -> Vec<String> {
    let tree = tree.trim();
    let Some(open) = tree.find('{') else {
        let path = tree.split(" as ").next().unwrap_or(tree);
        return vec![path.split_whitespace().collect()];
    };
    let prefix: String = tree[..open].split_whitespace().collect();
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    // Split the inner list at top-level commas.
    let mut items = Vec::new();
    let (mut depth, mut start) = (0, 0);
    for (i, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    items.push(&inner[start..]);
    items
        .into_iter()
        .map(str::trim)
        .filter(|item| !item.is_empty())
        .flat_map(expand_use)
        .map(|rest| {
            if rest == "self" {
                prefix.trim_end_matches("::").to_string()
            } else {
                format!("{prefix}{rest}")
            }
        })
        .collect()
}

/// Turns a path that starts with `crate`, `super` or `self` (as seen in `module`) into a
/// crate-rooted module path. Other paths give None, except with `relative` (a `use`
/// statement's path, which may start at a child module): then the path under `module`
/// (for another crate's path that names the file itself, which the graph ignores).
fn rooted(path: &str, module: &[String], relative: bool) -> Option<Vec<String>> {
    let mut segments = path.split("::").map(str::trim).filter(|s| !s.is_empty());
    let first = segments.next()?;
    let mut base: Vec<String> = match first {
        "crate" => Vec::new(),
        "self" => module.to_vec(),
        "super" => module[..module.len().saturating_sub(1)].to_vec(),
        _ if relative => [module, &[first.to_string()]].concat(),
        _ => return None,
    };
    for s in segments {
        if s == "super" {
            base.pop();
        } else if s == "*" {
            break;
        } else {
            let word: String = s
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if word.is_empty() {
                break;
            }
            base.push(word);
        }
    }
    Some(base)
}

/// The uses in a file's text (its unit-test module, after `#[cfg(test)]`, left out: its
/// `super::*` is the file itself). Comments are skipped.
fn uses_in(text: &str, module: &[String]) -> Vec<Use> {
    let mut out = Vec::new();
    let mut statement = String::new();
    let mut statement_line = 0;
    let mut statement_public = false;
    for (k, raw) in text.lines().enumerate() {
        let line = raw.split("//").next().unwrap_or("");
        if raw.trim_start().starts_with("#[cfg(test)]") {
            break;
        }
        let trimmed = line.trim_start();
        let public = trimmed.starts_with("pub ");
        let trimmed = trimmed.strip_prefix("pub ").unwrap_or(trimmed);
        let trimmed = trimmed
            .strip_prefix("pub(crate) ")
            .or_else(|| trimmed.strip_prefix("pub(super) "))
            .unwrap_or(trimmed);
        if statement.is_empty() && trimmed.starts_with("use ") {
            statement_line = k + 1;
            statement_public = public;
            statement.push_str(&trimmed[4..]);
        } else if !statement.is_empty() {
            statement.push_str(line);
        } else {
            // Paths written inline: crate::a::b, super::c, self::d.
            for start in ["crate::", "super::", "self::"] {
                let mut rest = line;
                while let Some(at) = rest.find(start) {
                    let before = rest[..at].chars().last();
                    let tail = &rest[at..];
                    let end = tail
                        .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                        .unwrap_or(tail.len());
                    let inside_a_word =
                        before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':');
                    if !inside_a_word && let Some(path) = rooted(&tail[..end], module, false) {
                        out.push(Use {
                            line: k + 1,
                            path,
                            reexport: false,
                        });
                    }
                    rest = &tail[end.max(1)..];
                }
            }
            continue;
        }
        if let Some(end) = statement.find(';') {
            for path in expand_use(&statement[..end]) {
                if let Some(path) = rooted(&path, module, true) {
                    out.push(Use {
                        line: statement_line,
                        path,
                        reexport: statement_public,
                    });
                }
            }
            statement.clear();
        }
    }
    out
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// A path as the messages and lists here write it: forward slashes.
fn slashed(path: &Path) -> String {
    path.to_string_lossy().replace('\\', "/")
}

/// Fails unless `found` is exactly the `known` list of a rule's exceptions: what is
/// found and not listed breaks the rule; what is listed and no longer found must leave
/// the list, so that it can only shrink.
fn assert_only_known(found: &BTreeSet<String>, known: &[&str], what: &str) {
    let known: BTreeSet<String> = known.iter().map(|s| s.to_string()).collect();
    let new: Vec<&String> = found.difference(&known).collect();
    let gone: Vec<&String> = known.difference(found).collect();
    assert!(
        new.is_empty() && gone.is_empty(),
        "{what}, not listed: {new:#?}\nlisted but no longer so (remove them from the list): \
         {gone:#?}"
    );
}

/// The source files of the crate and their uses, keyed by path relative to the repo.
struct Source {
    files: BTreeMap<PathBuf, Vec<Use>>,
    /// `pub use` re-exports of mod.rs / lib.rs files: (module, item) → the module path
    /// the item comes from.
    reexports: BTreeMap<(Vec<String>, String), Vec<String>>,
}

impl Source {
    fn read(root: &Path) -> Self {
        let mut files = BTreeMap::new();
        let mut reexports = BTreeMap::new();
        for file in rust_files(&root.join("src")) {
            let rel = file.strip_prefix(root).unwrap().to_path_buf();
            let text = std::fs::read_to_string(&file).unwrap();
            Self::add(&mut files, &mut reexports, rel, &text);
        }
        Self { files, reexports }
    }

    fn from_texts(texts: &[(&str, &str)]) -> Self {
        let mut files = BTreeMap::new();
        let mut reexports = BTreeMap::new();
        for (path, text) in texts {
            Self::add(&mut files, &mut reexports, PathBuf::from(path), text);
        }
        Self { files, reexports }
    }

    fn add(
        files: &mut BTreeMap<PathBuf, Vec<Use>>,
        reexports: &mut BTreeMap<(Vec<String>, String), Vec<String>>,
        rel: PathBuf,
        text: &str,
    ) {
        let module = module_of(&rel);
        let is_facade = rel.ends_with("mod.rs") || rel.ends_with("lib.rs");
        if is_facade {
            for line in text.lines() {
                let Some(tree) = line.trim().strip_prefix("pub use ") else {
                    continue;
                };
                for path in expand_use(tree.trim_end_matches(';')) {
                    let relative = format!("self::{path}");
                    if let Some(mut target) = rooted(&relative, &module, false) {
                        let item = target.pop().unwrap_or_default();
                        reexports.insert((module.clone(), item), target);
                    }
                }
            }
        }
        files.insert(rel, uses_in(text, &module));
    }

    /// The file a crate-rooted path names: its longest prefix that is a file, followed
    /// through a facade's re-export when the next segment is re-exported there.
    fn file_of(&self, path: &[String]) -> Option<PathBuf> {
        for len in (1..=path.len()).rev() {
            let prefix = &path[..len];
            let joined = prefix.join("/");
            let plain = PathBuf::from(format!("src/{joined}.rs"));
            if self.files.contains_key(&plain) {
                return Some(plain);
            }
            let facade = PathBuf::from(format!("src/{joined}/mod.rs"));
            if self.files.contains_key(&facade) {
                if let Some(item) = path.get(len)
                    && let Some(target) = self.reexports.get(&(prefix.to_vec(), item.clone()))
                    && target.as_slice() != prefix
                {
                    return self.file_of(target);
                }
                return Some(facade);
            }
        }
        None
    }

    /// Every rule broken, as "file:line: path (why)".
    fn broken_rules(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (file, uses) in &self.files {
            let name = slashed(file);
            for rule in RULES {
                let applies = rule.from.iter().any(|f| name.starts_with(f))
                    && !rule.except.iter().any(|e| name.starts_with(e));
                if !applies {
                    continue;
                }
                for u in uses {
                    if u.path
                        .first()
                        .is_some_and(|m| rule.to.contains(&m.as_str()))
                    {
                        out.push(format!(
                            "{name}:{}: uses crate::{} ({})",
                            u.line,
                            u.path.join("::"),
                            rule.why
                        ));
                    }
                }
            }
        }
        out
    }

    /// The file-to-file import graph. A facade's (mod.rs, lib.rs) re-exports are no
    /// imports: a path through them leads to the file that defines the item
    /// ([`Source::file_of`]); the crate root is no target.
    fn graph(&self) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
        let mut graph = BTreeMap::new();
        for (file, uses) in &self.files {
            let facade = file.ends_with("mod.rs") || file.ends_with("lib.rs");
            let targets: BTreeSet<PathBuf> = uses
                .iter()
                .filter(|u| !(facade && u.reexport))
                .filter_map(|u| self.file_of(&u.path))
                .filter(|t| t != file && !t.ends_with("lib.rs") && !t.ends_with("main.rs"))
                .collect();
            graph.insert(file.clone(), targets);
        }
        graph
    }

    /// The circles: each strongly connected group of two or more files, as its sorted
    /// files joined by " <-> ".
    fn circles(&self) -> BTreeSet<String> {
        let graph = self.graph();
        let reach = |from: &PathBuf| -> BTreeSet<PathBuf> {
            let mut seen = BTreeSet::new();
            let mut stack = vec![from.clone()];
            while let Some(f) = stack.pop() {
                for t in graph.get(&f).into_iter().flatten() {
                    if seen.insert(t.clone()) {
                        stack.push(t.clone());
                    }
                }
            }
            seen
        };
        let reachable: BTreeMap<&PathBuf, BTreeSet<PathBuf>> =
            graph.keys().map(|f| (f, reach(f))).collect();
        let mut out = BTreeSet::new();
        for (f, from_f) in &reachable {
            let group: BTreeSet<String> = from_f
                .iter()
                .filter(|g| reachable.get(g).is_some_and(|r| r.contains(*f)))
                .chain(from_f.contains(*f).then_some(*f))
                .map(|p| slashed(p))
                .collect();
            if group.len() >= 2 {
                out.insert(group.into_iter().collect::<Vec<_>>().join(" <-> "));
            }
        }
        out
    }
}

#[test]
fn the_source_keeps_the_dependency_rules() {
    let source = Source::read(Path::new(env!("CARGO_MANIFEST_DIR")));
    assert!(source.files.len() > 50, "{} files read", source.files.len());
    let broken = source.broken_rules();
    assert!(
        broken.is_empty(),
        "imports that break docs/architecture.md's rules:\n{}",
        broken.join("\n")
    );
}

#[test]
fn no_new_circle_of_imports_and_the_known_ones_are_listed() {
    let source = Source::read(Path::new(env!("CARGO_MANIFEST_DIR")));
    assert_only_known(
        &source.circles(),
        KNOWN_CIRCLES,
        "files that import each other in a circle (KNOWN_CIRCLES)",
    );
}

#[test]
fn a_forbidden_import_and_a_circle_are_caught_with_their_file_and_line() {
    // A small made-up crate: the engine importing the teacher (one rule broken, at its
    // line) and two nn files importing each other through a facade's re-export.
    let source = Source::from_texts(&[
        (
            "src/lib.rs",
            "pub mod engine;\npub mod nn;\npub mod avatar;\n",
        ),
        ("src/avatar/mod.rs", "pub struct Rig;\n"),
        (
            "src/engine/mod.rs",
            "//! The live loop.\nuse crate::nn::Recorder;\n\nfn f() {\n    let r = crate::avatar::Rig;\n}\n",
        ),
        (
            "src/nn/mod.rs",
            "pub mod ops;\npub mod kernels;\npub use ops::Recorder;\n",
        ),
        (
            "src/nn/ops.rs",
            "use super::kernels::{self, CONV};\npub struct Recorder;\n",
        ),
        (
            "src/nn/kernels.rs",
            "use super::Recorder;\npub const CONV: u32 = 1;\n",
        ),
        (
            "src/gpu/mod.rs",
            "use crate::nn::{ops::Recorder, kernels};\n",
        ),
    ]);
    let broken = source.broken_rules();
    assert_eq!(broken.len(), 3, "{broken:#?}");
    assert!(
        broken[0].starts_with("src/engine/mod.rs:5: uses crate::avatar::Rig"),
        "{broken:#?}"
    );
    assert!(
        broken[1].starts_with("src/gpu/mod.rs:1: uses crate::nn::ops::Recorder"),
        "{broken:#?}"
    );
    let circles = source.circles();
    assert_eq!(
        circles.into_iter().collect::<Vec<_>>(),
        ["src/nn/kernels.rs <-> src/nn/ops.rs"]
    );
    // The resolution behind them.
    assert_eq!(
        expand_use("super::{kernels::{self, CONV}, ops::Recorder as R}"),
        [
            "super::kernels",
            "super::kernels::CONV",
            "super::ops::Recorder"
        ]
    );
    assert_eq!(
        source.file_of(&["nn".into(), "Recorder".into()]),
        Some(PathBuf::from("src/nn/ops.rs"))
    );
}

#[test]
fn no_source_file_is_longer_than_the_limit_but_the_listed_ones() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let long: BTreeSet<String> = rust_files(&root.join("src"))
        .into_iter()
        .filter(|f| std::fs::read_to_string(f).unwrap().lines().count() > MAX_LINES)
        .map(|f| slashed(f.strip_prefix(root).unwrap()))
        .collect();
    assert_only_known(
        &long,
        KNOWN_LONG_FILES,
        &format!("files over {MAX_LINES} lines (KNOWN_LONG_FILES)"),
    );
}

#[test]
fn each_public_type_name_means_one_thing() {
    // `pub struct|enum|type|trait NAME` anywhere in src/ (gpu_struct! bodies included):
    // one name, one definition, so that a name read in any file means the same type.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut defined: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for file in rust_files(&root.join("src")) {
        let rel = slashed(file.strip_prefix(root).unwrap());
        for (k, line) in std::fs::read_to_string(&file).unwrap().lines().enumerate() {
            let words: Vec<&str> = line.split_whitespace().collect();
            if let [first, kind, name, ..] = words[..]
                && first == "pub"
                && ["struct", "enum", "type", "trait"].contains(&kind)
            {
                let name: String = name
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                defined
                    .entry(name)
                    .or_default()
                    .push(format!("{rel}:{}", k + 1));
            }
        }
    }
    assert!(defined.len() > 100, "{} public types read", defined.len());
    let twice: Vec<String> = defined
        .iter()
        .filter(|(_, at)| at.len() > 1)
        .map(|(name, at)| format!("{name}: {}", at.join(", ")))
        .collect();
    assert!(
        twice.is_empty(),
        "public type names defined more than once:\n{}",
        twice.join("\n")
    );
}
