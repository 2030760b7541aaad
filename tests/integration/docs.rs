//! The documents a newcomer reads: short enough to read, and their figures the one table's.

use crate::common::cli::{morph, ok, root};

/// The presets' figures in docs/accuracy.md's "Presets" table, row by row: (preset, IoU, fill,
/// wall, peak memory).
fn presets_table() -> Vec<[String; 5]> {
    let text = std::fs::read_to_string(root().join("docs/accuracy.md")).unwrap();
    let section = text.split("## Presets").nth(1).expect("a Presets section");
    let section = section.split("\n## ").next().unwrap();
    section
        .lines()
        .filter(|l| l.starts_with("| `"))
        .map(|l| {
            let cells: Vec<String> = l
                .trim_matches('|')
                .split('|')
                .map(|c| c.trim().trim_matches('`').to_string())
                .collect();
            [0, 1, 2, 3, 4].map(|i| cells.get(i).cloned().unwrap_or_default())
        })
        .collect()
}

/// `morph --help` states each preset's measured figures as the table does.
#[test]
fn the_helps_preset_figures_are_the_tables() {
    let rows = presets_table();
    assert_eq!(rows.len(), 3, "{rows:?}");
    let help = morph(&["--help"]);
    ok(&help);
    let text = String::from_utf8_lossy(&help.stdout);
    for [preset, iou, fill, wall, memory] in rows {
        let line = text
            .lines()
            .find(|l| {
                l.trim_start().starts_with(&format!("{preset} ")) && l.contains("sphere -> spot")
            })
            .unwrap_or_else(|| panic!("no {preset} line in --help"));
        let mut says = format!("IoU {iou}, fill {fill}, {wall}");
        if !memory.is_empty() {
            says += &format!(", {memory}");
        }
        assert!(
            line.ends_with(&says),
            "--help: {line:?}, the table: {says:?}"
        );
    }
}

/// README.md at most 250 lines, every reference document at most 500, and no version number in
/// a reference document's headings (the history is in docs/lab/).
#[test]
fn the_documents_stay_short_and_say_what_is() {
    let lines = |p: &std::path::Path| std::fs::read_to_string(p).unwrap().lines().count();
    assert!(lines(&root().join("README.md")) <= 250);
    let version = |h: &str| {
        h.split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .any(|w| w.split('.').filter(|p| !p.is_empty()).count() == 3)
    };
    for entry in std::fs::read_dir(root().join("docs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") {
            assert!(
                lines(&path) <= 500,
                "{} is {} lines",
                path.display(),
                lines(&path)
            );
            let text = std::fs::read_to_string(&path).unwrap();
            for h in text.lines().filter(|l| l.starts_with('#')) {
                assert!(!version(h), "{}: {h}", path.display());
            }
        }
    }
}

/// Every local link and image of README.md, CHANGELOG.md, docs/ and docs/lab/ names a file
/// that is there.
#[test]
fn every_local_link_of_the_documents_resolves() {
    let mut files = vec![root().join("README.md"), root().join("CHANGELOG.md")];
    for dir in ["docs", "docs/lab"] {
        for entry in std::fs::read_dir(root().join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "md") {
                files.push(path);
            }
        }
    }
    let mut broken = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap();
        for target in text
            .split("](")
            .skip(1)
            .filter_map(|rest| rest.split(')').next())
        {
            let target = target.split('#').next().unwrap_or("");
            if target.is_empty() || target.contains("://") || target.contains(' ') {
                continue;
            }
            if !file.parent().unwrap().join(target).exists() {
                broken.push(format!("{}: {target}", file.display()));
            }
        }
    }
    assert!(broken.is_empty(), "{broken:#?}");
}
