//! Scene files (`morph --scene shot.toml`): a shot's meshes and every setting, in TOML or
//! JSON. The keys are [`MorphSettings`]'s field names (the command line's option names with
//! `_` for `-`; `steps_per_segment` is `--steps`), nested tables for its parts
//! (`[material]`, `[optimizer]`, `[ground]`, `[[colliders]]`, `[walls]`), and two more:
//! `source`, the mesh to start from, and `targets`, the meshes to become in keyframe order.
//! Mesh paths are relative to the file's folder. `seconds` may stand for `frames`, as
//! `--seconds` does on the command line.
//!
//! A file is read over its preset's settings (`preset = "final"`; the default preset when it
//! names none): only the keys it gives change anything. A key the settings do not have is an
//! error naming the key, the file and the line. `[material]` may give `youngs_modulus` and
//! `poisson_ratio` in place of `mu` and `lambda`.
//!
//! A morph writes its resolved scene (every setting, absolute mesh paths) as `scene.toml` in
//! its output folder: `morph --scene OUT/scene.toml` runs it again, bit for bit.

use super::settings::{self, MorphSettings, Preset};
use std::path::{Path, PathBuf};

/// The name of the resolved scene in an output folder.
pub const RESOLVED: &str = "scene.toml";

/// A shot read from a scene file.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// The file it came from.
    pub path: PathBuf,
    pub source: Option<PathBuf>,
    pub targets: Vec<PathBuf>,
    /// The preset's settings with the file's keys applied.
    pub settings: MorphSettings,
}

impl SceneFile {
    /// Reads `path` (TOML, or JSON when it ends in `.json`) over the settings of `preset`, or
    /// of the preset the file names when `preset` is `None`.
    pub fn read(path: &Path, preset: Option<Preset>) -> Result<SceneFile, String> {
        let text = crate::files::read_to_string(path, crate::files::SMALL_FILE_BYTES)
            .map_err(|e| format!("cannot read scene file '{}': {e}", path.display()))?;
        // A byte-order mark (editors on Windows write one) is not part of the text.
        SceneFile::parse(text.strip_prefix('\u{feff}').unwrap_or(&text), path, preset)
    }

    /// [`SceneFile::read`] on text already read from `path`.
    pub fn parse(text: &str, path: &Path, preset: Option<Preset>) -> Result<SceneFile, String> {
        let shown = path.display();
        let json = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let mut table = table_of(text, &shown, json)?;
        let (source, targets) = take_inputs(&mut table, path.parent(), &shown)?;
        let preset = match (preset, table.remove("preset")) {
            (Some(p), _) => p,
            (None, Some(v)) => v.try_into().map_err(|e: toml::de::Error| {
                format!("scene file '{shown}': preset: {}", one_line(&e.to_string()))
            })?,
            (None, None) => Preset::default(),
        };
        let settings = layer(MorphSettings::preset(preset), table)
            .map_err(|e| format!("scene file '{shown}': {e}"))?;
        Ok(SceneFile {
            path: path.to_path_buf(),
            source,
            targets,
            settings,
        })
    }

    /// The resolved scene of a run: every setting and the meshes' absolute paths, as TOML
    /// that [`SceneFile::parse`] reads back to the same settings.
    pub fn resolved(settings: &MorphSettings, source: &Path, targets: &[PathBuf]) -> String {
        let absolute = |p: &Path| {
            std::path::absolute(p)
                .unwrap_or_else(|_| p.to_path_buf())
                .display()
                .to_string()
        };
        let mut settings = settings.clone();
        for mesh in settings.world.meshes_mut() {
            *mesh = PathBuf::from(absolute(mesh));
        }
        let mut table = toml::Table::new();
        table.insert("source".into(), absolute(source).into());
        table.insert(
            "targets".into(),
            toml::Value::Array(targets.iter().map(|t| absolute(t).into()).collect()),
        );
        let body = toml::Table::try_from(&settings).expect("settings serialize to TOML");
        table.extend(body);
        format!(
            "# The resolved scene of a morph run: `morph --scene scene.toml -o OUT` runs it again,\n# bit for bit (docs/scenes.md).\n{}",
            toml::to_string(&table).expect("a table serializes")
        )
    }
}

/// The first key of the file's `table` that the settings do not have, as a dotted path
/// (`ground.friction`, `colliders.0.mesh`). The settings' own deserializer decides, through
/// `serde_ignored`, so every setting a scene can hold is known here without a list of its own.
/// The keys the file itself reads (`source`, `targets`, `seconds`, `preset`, and Young's
/// modulus and Poisson's ratio in `[material]`) are known too.
fn unknown_key(table: &toml::Table) -> Option<String> {
    let mut given = table.clone();
    for key in ["source", "targets", "preset"] {
        given.remove(key);
    }
    if let Some(toml::Value::Table(shot)) = given.get_mut("shot") {
        shot.remove("seconds");
    }
    if let Some(toml::Value::Table(m)) = given
        .get_mut("body")
        .and_then(|b| b.as_table_mut())
        .and_then(|b| b.get_mut("material"))
    {
        m.remove("youngs_modulus");
        m.remove("poisson_ratio");
    }
    // Over a whole preset, so the file's keys alone need not make complete settings.
    let mut merged = toml::Table::try_from(MorphSettings::default()).expect("settings serialize");
    merge(&mut merged, given);
    let mut first = None;
    // A value of the wrong type ends this pass early; reading the settings reports it.
    let _: Result<MorphSettings, _> =
        serde_ignored::deserialize(toml::Value::Table(merged), |path| {
            first.get_or_insert_with(|| dotted(&path));
        });
    first
}

/// A key's path as the file writes it: tables and list items by name and index, joined by dots.
fn dotted(path: &serde_ignored::Path) -> String {
    use serde_ignored::Path;
    let join = |parent: &Path, part: String| match dotted(parent) {
        p if p.is_empty() => part,
        p => format!("{p}.{part}"),
    };
    match path {
        Path::Root => String::new(),
        Path::Seq { parent, index } => join(parent, index.to_string()),
        Path::Map { parent, key } => join(parent, key.clone()),
        Path::Some { parent }
        | Path::NewtypeStruct { parent }
        | Path::NewtypeVariant { parent } => dotted(parent),
    }
}

/// The 1-based line where the last part of dotted `key` first appears as a key.
fn line_of(text: &str, key: &str, json: bool) -> Option<usize> {
    let name = key.rsplit('.').next()?;
    text.lines()
        .position(|line| {
            let t = line.trim_start();
            if json {
                t.contains(&format!("\"{name}\""))
            } else {
                let t = t.trim_start_matches('[').trim_start();
                t.strip_prefix(name).is_some_and(|rest| {
                    rest.trim_start().starts_with('=') || rest.trim_start().starts_with(']')
                }) || t.strip_prefix(&format!("\"{name}\"")).is_some()
            }
        })
        .map(|i| i + 1)
}

/// `base` with the keys of `table` (nested by part, checked) applied, by the rules the command
/// line follows too: a resolution replaces a particle budget, a grid given turns the thin
/// parts' rule off, a frame every n steps (or a set dt) without fps replaces the frame rate,
/// `seconds` stands for `frames`, segments without frames replace a frame count, an optimizer
/// without a step size takes its own default step.
fn layer(base: MorphSettings, mut table: toml::Table) -> Result<MorphSettings, String> {
    if let Some(toml::Value::Table(m)) = part_mut(&mut table, "body").get_mut("material") {
        young_poisson_to_lame(m)?;
    }
    let given = |table: &toml::Table, key: &str| {
        let part = settings::part_of(key).unwrap_or("shot");
        table
            .get(part)
            .and_then(toml::Value::as_table)
            .is_some_and(|t| t.contains_key(key))
    };
    let had_frames = given(&table, "frames");
    let no_fps = !given(&table, "fps") && (given(&table, "frame_every") || given(&table, "dt"));
    let no_frames = given(&table, "segments") && !had_frames;
    let optimizer = (table.get("method"))
        .and_then(|m| m.get("optimizer"))
        .and_then(toml::Value::as_table);
    let own_step =
        optimizer.is_some_and(|o| o.contains_key("kind") && !o.contains_key("learning_rate"));
    let seconds = part_mut(&mut table, "shot").remove("seconds");
    let mut merged = toml::Table::try_from(&base).expect("settings serialize to TOML");
    // A resolution given replaces the base's particle budget; a budget given wins over any
    // resolution.
    if given(&table, "resolution") && !given(&table, "particles") {
        part_mut(&mut merged, "body").remove("particles");
    }
    // A grid or particles per cell given are what is asked for: the thin parts' rule does
    // not change them (unless it is given too).
    let sized = given(&table, "resolution") || given(&table, "particles_per_cell");
    if sized && !given(&table, "thin_across") {
        part_mut(&mut merged, "body").insert("thin_across".into(), toml::Value::Float(0.0));
    }
    merge(&mut merged, table);
    let mut settings: MorphSettings = toml::Value::Table(merged)
        .try_into()
        .map_err(|e: toml::de::Error| one_line(&e.to_string()))?;
    if no_fps {
        settings.shot.fps = None;
    }
    if no_frames {
        settings.shot.frames = None;
    }
    if own_step {
        settings.method.optimizer.learning_rate =
            settings.method.optimizer.kind.default_learning_rate();
    }
    if let Some(v) = seconds {
        if had_frames {
            return Err("give `frames` or `seconds`, not both".into());
        }
        let seconds = match v {
            toml::Value::Float(f) => f,
            toml::Value::Integer(i) => i as f64,
            other => return Err(format!("`seconds` must be a number, got {other}")),
        };
        settings.shot.frames =
            Some((settings.frames_for(seconds)).map_err(|e| e.replace("--seconds", "seconds"))?);
    }
    Ok(settings)
}

/// `base` with settings given by name, `KEY=VALUE` each (`morph --set`): a key as a scene file
/// writes it (`path_weight`, `method.path_weight`, `optimizer.iterations`, or an alias such as
/// `iterations`; `-` may stand for `_`), a value as TOML writes it (`2`, `0.5`, `true`,
/// `[24, 48]`) or a bare word (`line-search`). A key the settings lack is refused naming the
/// keys there are.
pub fn with_keys(base: MorphSettings, pairs: &[String]) -> Result<MorphSettings, String> {
    if pairs.is_empty() {
        return Ok(base);
    }
    let mut table = toml::Table::new();
    for pair in pairs {
        let (key, text) = pair
            .split_once('=')
            .ok_or_else(|| format!("--set {pair}: give KEY=VALUE"))?;
        let path: Vec<String> = key.trim().split('.').map(|k| k.replace('-', "_")).collect();
        if path.iter().any(String::is_empty) {
            return Err(format!("--set {pair}: `{key}` is not a key"));
        }
        let value = toml::from_str::<toml::Table>(&format!("v = {text}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(text.trim().to_string()));
        match insert_at(&mut table, &path, value) {
            Ok(false) => {}
            Ok(true) => return Err(format!("--set: `{key}` is given twice")),
            Err(name) => return Err(format!("--set {pair}: `{name}` is given a value and keys")),
        }
    }
    nest(&mut table).map_err(|e| format!("--set: {e}"))?;
    if let Some(key) = unknown_key(&table) {
        return Err(format!(
            "--set: unknown key `{key}`; the keys: {} (`morph help method` says what each does)",
            settings::knobs::names().join(", ")
        ));
    }
    layer(base, table).map_err(|e| format!("--set: {e}"))
}

/// Moves each setting the file gives flat into its part's table (`frames = 97` becomes
/// `[shot] frames = 97`; `seconds` is the shot's), so that a key may be given either way. A
/// key given both ways is refused.
fn nest(table: &mut toml::Table) -> Result<(), String> {
    unalias(table)?;
    let flat: Vec<String> = (table.keys())
        .filter(|k| settings::part_of(k).is_some() || *k == "seconds")
        .cloned()
        .collect();
    if let Some((part, _)) =
        (settings::PARTS.iter()).find(|(p, _)| table.get(*p).is_some_and(|v| !v.is_table()))
    {
        return Err(format!("`{part}` must be a table of settings"));
    }
    for key in flat {
        let part = settings::part_of(&key).unwrap_or("shot");
        let value = table.remove(&key).expect("listed above");
        if part_mut(table, part).insert(key.clone(), value).is_some() {
            return Err(format!(
                "`{key}` is given twice: on its own and in [{part}]"
            ));
        }
    }
    Ok(())
}

/// The command line's names for settings that live deeper (`iterations` for
/// `optimizer.iterations`, `steps` for `steps_per_segment`, `optimizer = "adam"` for
/// `optimizer.kind`), given flat, moved to where the settings hold them.
fn unalias(table: &mut toml::Table) -> Result<(), String> {
    if let Some(kind) = table.get("optimizer").filter(|v| v.is_str()).cloned() {
        table.insert(
            "optimizer".into(),
            toml::Value::Table([("kind".to_string(), kind)].into_iter().collect()),
        );
    }
    for (alias, path) in settings::knobs::ALIASES {
        let Some(value) = table.remove(*alias) else {
            continue;
        };
        match insert_at(table, path, value) {
            Ok(false) => {}
            Ok(true) => {
                return Err(format!(
                    "`{alias}` is given twice: as it is and as `{}`",
                    path.join(".")
                ));
            }
            Err(name) => return Err(format!("`{name}` must be a table of settings")),
        }
    }
    Ok(())
}

/// `value` at the dotted `path` of `table`, the tables on the way made where missing: whether
/// the key was there already, or the name on the way that holds a value, not a table.
fn insert_at<S: AsRef<str>>(
    table: &mut toml::Table,
    path: &[S],
    value: toml::Value,
) -> Result<bool, String> {
    let (last, tables) = path.split_last().expect("a key");
    let mut at = table;
    for name in tables.iter().map(AsRef::as_ref) {
        at = match at
            .entry(name)
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        {
            toml::Value::Table(t) => t,
            _ => return Err(name.to_string()),
        };
    }
    Ok(at.insert(last.as_ref().to_string(), value).is_some())
}

/// The table of part `part` (made empty when the file gives none of its keys; [`nest`] has
/// refused a part that is not a table).
fn part_mut<'a>(table: &'a mut toml::Table, part: &str) -> &'a mut toml::Table {
    let entry = table
        .entry(part)
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    match entry {
        toml::Value::Table(t) => t,
        other => unreachable!("part `{part}` is {other}, which nest refuses"),
    }
}

/// `over`'s values replace `base`'s; tables merge key by key.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// `[material]` with `youngs_modulus` and/or `poisson_ratio`: the Lamé parameters they make
/// (the other one from the default material).
fn young_poisson_to_lame(m: &mut toml::Table) -> Result<(), String> {
    let e = m.remove("youngs_modulus");
    let nu = m.remove("poisson_ratio");
    if e.is_none() && nu.is_none() {
        return Ok(());
    }
    if m.contains_key("mu") || m.contains_key("lambda") {
        return Err(
            "[material] gives both youngs_modulus/poisson_ratio and mu/lambda; give one pair"
                .into(),
        );
    }
    let number = |v: toml::Value, key: &str| -> Result<f64, String> {
        match v {
            toml::Value::Float(f) => Ok(f),
            toml::Value::Integer(i) => Ok(i as f64),
            other => Err(format!("[material] {key} must be a number, got {other}")),
        }
    };
    let d = MorphSettings::default().body.material;
    let (e0, nu0) = crate::engine::material::young_poisson_from_lame(d.mu, d.lambda);
    let e = e
        .map(|v| number(v, "youngs_modulus"))
        .transpose()?
        .unwrap_or(e0);
    let nu = nu
        .map(|v| number(v, "poisson_ratio"))
        .transpose()?
        .unwrap_or(nu0);
    if !(e.is_finite() && e > 0.0) {
        return Err(format!("[material] youngs_modulus must be > 0, got {e}"));
    }
    if !(0.0..=0.49).contains(&nu) {
        return Err(format!(
            "[material] poisson_ratio must be between 0 and 0.49, got {nu}"
        ));
    }
    let (mu, lambda) = crate::engine::material::lame_from_young_poisson(e, nu);
    m.insert("mu".into(), mu.into());
    m.insert("lambda".into(), lambda.into());
    Ok(())
}

/// The first line of a multi-line parser message, with its location kept.
fn one_line(message: &str) -> String {
    // toml's messages are "TOML parse error at line L, column C\n  |\nL | ...\n  | ^\nwhat".
    let lines: Vec<&str> = message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    match (lines.first(), lines.last()) {
        (Some(first), Some(last)) if lines.len() > 1 => {
            let at = first.trim_start_matches("TOML parse error at ");
            crate::files::short_message(&format!("{at}: {last}"))
        }
        _ => crate::files::short_message(message),
    }
}

/// A JSON value whose objects never repeat a key: `serde_json` keeps the last of repeated
/// keys, so a scene file naming a setting twice would run with one of them silently (TOML's
/// parser refuses a repeated key itself).
struct Strict(serde_json::Value);

impl<'de> serde::Deserialize<'de> for Strict {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Strict, D::Error> {
        d.deserialize_any(StrictVisitor).map(Strict)
    }
}

struct StrictVisitor;

impl<'de> serde::de::Visitor<'de> for StrictVisitor {
    type Value = serde_json::Value;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_i64<E>(self, v: i64) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_u64<E>(self, v: u64) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_f64<E>(self, v: f64) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_str<E>(self, v: &str) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_string<E>(self, v: String) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_unit<E>(self) -> Result<Self::Value, E> {
        Ok(serde_json::Value::Null)
    }
    fn visit_none<E>(self) -> Result<Self::Value, E> {
        Ok(serde_json::Value::Null)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut items = Vec::new();
        while let Some(Strict(v)) = seq.next_element()? {
            items.push(v);
        }
        Ok(items.into())
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut object = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let Strict(value) = map.next_value()?;
            if object.insert(key.clone(), value).is_some() {
                return Err(serde::de::Error::custom(format!(
                    "the key `{}` is given twice",
                    crate::files::quote_short(&key)
                )));
            }
        }
        Ok(object.into())
    }
}

/// The file's text as a table (TOML, or JSON by its extension), refused with the line of
/// its first unknown key.
fn table_of(text: &str, shown: &dyn std::fmt::Display, json: bool) -> Result<toml::Table, String> {
    let table: toml::Table = if json {
        let value = serde_json::from_str::<Strict>(text)
            .map_err(|e| format!("scene file '{shown}': {}", one_line(&e.to_string())))?
            .0;
        toml::Table::try_from(value).map_err(|e| {
            format!(
                "scene file '{shown}': {} (the top level must be an object)",
                one_line(&e.to_string())
            )
        })?
    } else {
        text.parse().map_err(|e: toml::de::Error| {
            format!("scene file '{shown}': {}", one_line(&e.to_string()))
        })?
    };
    let mut table = table;
    nest(&mut table).map_err(|e| format!("scene file '{shown}': {e}"))?;
    if let Some(key) = unknown_key(&table) {
        let line = line_of(text, &key, json).map_or(String::new(), |l| format!(" line {l}:"));
        return Err(format!(
            "scene file '{shown}':{line} unknown key `{key}` (the keys are the settings' names; see docs/scenes.md)"
        ));
    }
    Ok(table)
}

/// The source and the targets the table names, removed from it, and the colliders' meshes:
/// each path relative to `dir` (the file's folder) unless absolute.
fn take_inputs(
    table: &mut toml::Table,
    dir: Option<&Path>,
    shown: &dyn std::fmt::Display,
) -> Result<(Option<PathBuf>, Vec<PathBuf>), String> {
    let dir = dir.unwrap_or(Path::new("."));
    let resolve = |p: &str| -> PathBuf {
        let p = PathBuf::from(p);
        if p.is_absolute() { p } else { dir.join(p) }
    };
    let path_of = |v: toml::Value, key: &str| -> Result<PathBuf, String> {
        match v {
            toml::Value::String(s) => Ok(resolve(&s)),
            other => Err(format!(
                "scene file '{shown}': `{key}` must be a file path, got {other}"
            )),
        }
    };
    let source = table
        .remove("source")
        .map(|v| path_of(v, "source"))
        .transpose()?;
    let targets = match table.remove("targets") {
        None => Vec::new(),
        Some(toml::Value::Array(a)) => a
            .into_iter()
            .map(|v| path_of(v, "targets"))
            .collect::<Result<_, _>>()?,
        Some(other) => {
            return Err(format!(
                "scene file '{shown}': `targets` must be a list of mesh paths, got {other}"
            ));
        }
    };
    // The meshes of colliders, given by the shorthand (`mesh`) or in the list (`shape.path`).
    let world = part_mut(table, "world");
    let shorthand = world.get_mut("colliders").and_then(|c| c.as_array_mut());
    for c in shorthand.into_iter().flatten() {
        if let Some(toml::Value::String(m)) = c.get_mut("mesh") {
            *m = resolve(m).display().to_string();
        }
    }
    let listed = world.get_mut("effects").and_then(|e| e.as_array_mut());
    for e in listed.into_iter().flatten() {
        if let Some(toml::Value::String(p)) = e.get_mut("shape").and_then(|s| s.get_mut("path")) {
            *p = resolve(p).display().to_string();
        }
    }
    Ok((source, targets))
}

#[cfg(test)]
mod tests;
