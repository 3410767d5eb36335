//! Channel roles: which channels are the colour, its variance or halves, the
//! features with their variances, and the light layers.
//!
//! Automatic detection follows the naming of production AOVs as in
//! `../shared/scenes` (`R,G,B`, `var.R`, `A.R`/`B.R`, `albedo.R`,
//! `albedo_var.R`, `N.X`, `N_var.X`, `Z`, `Z_var`, `direct.R`,
//! `var.direct.R`); `--map ROLE=CH,CH,...` names channels for any other
//! naming.

use std::collections::BTreeMap;
use std::path::Path;

use crate::error::Error;
use crate::filter::{Buffer, Feature, FrameInputs, VarianceSource};

use super::Frame;

/// How to choose the variance of the mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum VarianceChoice {
    /// Sample variance when present, else half buffers.
    #[default]
    Auto,
    /// The renderer's sample-variance channels.
    Sample,
    /// `(A - B)^2 / 4` from the two half buffers.
    Halves,
}

/// Which features or layers to use.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum Selection {
    /// Detect from the channel names.
    #[default]
    Auto,
    /// Use none.
    None,
    /// Use exactly these (by name).
    List(Vec<String>),
}

impl std::str::FromStr for Selection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "auto" => Selection::Auto,
            "none" => Selection::None,
            list => {
                let names: Vec<String> =
                    list.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect();
                if names.is_empty() {
                    return Err("expected auto, none or a comma-separated list of names".into());
                }
                Selection::List(names)
            }
        })
    }
}

/// What the user asked for.
#[derive(Clone, Debug, Default)]
pub struct RoleOptions {
    /// Variance source.
    pub variance: VarianceChoice,
    /// Features to use.
    pub features: Selection,
    /// Light layers to use.
    pub layers: Selection,
    /// Explicit mappings `ROLE=CH,CH,...` (see [`MAP_HELP`]).
    pub maps: Vec<String>,
}

/// Help text for `--map`.
pub const MAP_HELP: &str = "Explicit channel mapping ROLE=CH[,CH...]; roles: color, variance, A, B, \
feature.NAME, feature-var.NAME, layer.NAME, layer-var.NAME (repeatable)";

/// Channel names of a buffer and its variance.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum VarianceRole {
    /// Variance channels, one per colour channel.
    Sample(Vec<String>),
    /// Half buffers A and B.
    Halves(Vec<String>, Vec<String>),
}

/// A feature's channels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FeatureRole {
    /// Feature name.
    pub name: String,
    /// Its channels.
    pub channels: Vec<String>,
    /// Its variance channels, if any.
    pub variance: Option<Vec<String>>,
}

/// A light layer's channels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LayerRole {
    /// Layer name.
    pub name: String,
    /// Its channels (same count as the colour).
    pub channels: Vec<String>,
    /// Its variance.
    pub variance: VarianceRole,
}

/// The roles chosen for a frame's channels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelRoles {
    /// Colour channels.
    pub colour: Vec<String>,
    /// Colour variance.
    pub variance: VarianceRole,
    /// Guide features.
    pub features: Vec<FeatureRole>,
    /// Light layers.
    pub layers: Vec<LayerRole>,
    /// Remarks on what was detected but not used, and why.
    pub notes: Vec<String>,
}

struct Names<'a> {
    all: &'a [String],
}

impl Names<'_> {
    fn has(&self, n: &str) -> bool {
        self.all.iter().any(|c| c == n)
    }
    fn all_present(&self, names: &[String]) -> bool {
        names.iter().all(|n| self.has(n))
    }
    /// Channels of group `g` (`g.X`, not deeper), in file order.
    fn group(&self, g: &str) -> Vec<String> {
        let prefix = format!("{g}.");
        self.all.iter().filter(|c| c.strip_prefix(&prefix).is_some_and(|rest| !rest.contains('.'))).cloned().collect()
    }
}

fn leaf(name: &str) -> &str {
    name.rsplit('.').next().unwrap_or(name)
}

fn group_of(name: &str) -> &str {
    name.rfind('.').map_or("", |i| &name[..i])
}

/// Variance channel candidates for `channels` (all in one group).
fn variance_candidates(channels: &[String]) -> Vec<Vec<String>> {
    let g = group_of(&channels[0]);
    let leaves: Vec<&str> = channels.iter().map(|c| leaf(c)).collect();
    let mk = |f: &dyn Fn(&str) -> String| leaves.iter().map(|l| f(l)).collect::<Vec<_>>();
    if g.is_empty() {
        vec![
            mk(&|l| format!("var.{l}")),
            mk(&|l| format!("variance.{l}")),
            mk(&|l| format!("{l}_var")),
            mk(&|l| format!("{l}.var")),
        ]
    } else {
        vec![
            mk(&|l| format!("var.{g}.{l}")),
            mk(&|l| format!("{g}_var.{l}")),
            mk(&|l| format!("{g}.var.{l}")),
            mk(&|l| format!("variance.{g}.{l}")),
        ]
    }
}

fn find_variance(names: &Names<'_>, channels: &[String]) -> Option<Vec<String>> {
    variance_candidates(channels).into_iter().find(|c| names.all_present(c))
}

/// Feature names tried by `--features auto`, with the channel groups that carry them.
const AUTO_FEATURES: &[(&str, &[&str])] = &[
    ("albedo", &["albedo", "Albedo", "diffuse_albedo"]),
    ("normal", &["N", "normal", "Normal", "normals"]),
    ("depth", &["Z", "depth", "Depth"]),
];

/// Light layers tried by `--layers auto`.
const AUTO_LAYERS: &[&str] = &["direct", "indirect"];

fn resolve_feature_channels(names: &Names<'_>, name: &str) -> Option<Vec<String>> {
    let g = names.group(name);
    if !g.is_empty() {
        return Some(g);
    }
    names.has(name).then(|| vec![name.to_string()])
}

fn err(path: &Path, names: &[String], message: impl Into<String>) -> Error {
    // A file may hold thousands of channels: list the first ones.
    const SHOWN: usize = 60;
    let mut found = names.iter().take(SHOWN).cloned().collect::<Vec<_>>().join(", ");
    if names.len() > SHOWN {
        found.push_str(&format!(", ... ({} channels in all; `nldenoise info` lists them)", names.len()));
    }
    if names.is_empty() {
        found = "none".into();
    }
    Error::Channels { path: path.to_path_buf(), message: message.into(), found }
}

/// Choose the roles of a frame's channels.
pub fn detect(path: &Path, channel_names: &[String], opts: &RoleOptions) -> Result<ChannelRoles, Error> {
    let names = Names { all: channel_names };
    let mut maps: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for m in &opts.maps {
        let (role, list) = m
            .split_once('=')
            .ok_or_else(|| err(path, channel_names, format!("--map {m:?} is not ROLE=CH[,CH...]; {MAP_HELP}")))?;
        let list: Vec<String> = list.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect();
        for ch in &list {
            if !names.has(ch) {
                return Err(err(
                    path,
                    channel_names,
                    format!("--map {role}=... names channel {ch:?}, which the file does not have"),
                ));
            }
        }
        if list.is_empty() {
            return Err(err(path, channel_names, format!("--map {role}= names no channel")));
        }
        maps.insert(role.to_string(), list);
    }
    let mut notes = Vec::new();

    // Colour.
    let colour = match maps.remove("color").or_else(|| maps.remove("colour")) {
        Some(c) => c,
        None => {
            let rgb: Vec<String> = ["R", "G", "B"].iter().map(|s| s.to_string()).collect();
            if names.all_present(&rgb) {
                rgb
            } else {
                return Err(err(path, channel_names, "no colour channels R,G,B; name them with --map color=CH,CH,CH"));
            }
        }
    };
    let n = colour.len();
    let check_count = |role: &str, v: &[String]| {
        if v.len() != n {
            Err(err(path, channel_names, format!("{role} has {} channels but the colour has {n}", v.len())))
        } else {
            Ok(())
        }
    };

    // Variance of the colour.
    let sample = match maps.remove("variance") {
        Some(v) => Some(v),
        None => find_variance(&names, &colour),
    };
    let halves = match (maps.remove("A"), maps.remove("B")) {
        (Some(a), Some(b)) => Some((a, b)),
        (None, None) => {
            let a: Vec<String> = colour.iter().map(|c| format!("A.{}", leaf(c))).collect();
            let b: Vec<String> = colour.iter().map(|c| format!("B.{}", leaf(c))).collect();
            (names.all_present(&a) && names.all_present(&b)).then_some((a, b))
        }
        _ => {
            return Err(err(path, channel_names, "--map A=... and --map B=... must be given together"));
        }
    };
    if let Some(s) = &sample {
        check_count("the variance", s)?;
    }
    if let Some((a, b)) = &halves {
        check_count("half buffer A", a)?;
        check_count("half buffer B", b)?;
    }
    let variance = match (opts.variance, sample, halves) {
        (VarianceChoice::Sample, Some(s), _) | (VarianceChoice::Auto, Some(s), _) => VarianceRole::Sample(s),
        (VarianceChoice::Halves, _, Some((a, b))) | (VarianceChoice::Auto, None, Some((a, b))) => {
            VarianceRole::Halves(a, b)
        }
        (VarianceChoice::Sample, None, _) => {
            return Err(err(
                path,
                channel_names,
                "--variance sample: no variance channels for the colour (e.g. var.R); map them with --map variance=...",
            ));
        }
        (VarianceChoice::Halves, _, None) => {
            return Err(err(
                path,
                channel_names,
                "--variance halves: no half buffers (e.g. A.R and B.R); map them with --map A=... --map B=...",
            ));
        }
        (VarianceChoice::Auto, None, None) => {
            return Err(err(
                path,
                channel_names,
                "no variance for the colour: need sample variance (e.g. var.R) or half buffers (A.R, B.R); map them with --map",
            ));
        }
    };

    // Features.
    let mut features = Vec::new();
    let mapped_features: Vec<String> =
        maps.keys().filter_map(|k| k.strip_prefix("feature.")).map(str::to_string).collect();
    let wanted: Vec<(String, Option<Vec<String>>)> = match &opts.features {
        Selection::None => Vec::new(),
        Selection::Auto => {
            let mut v = Vec::new();
            for (_, groups) in AUTO_FEATURES {
                if let Some(ch) = groups.iter().find_map(|g| resolve_feature_channels(&names, g)) {
                    v.push((group_name(&ch), Some(ch)));
                }
            }
            v
        }
        Selection::List(list) => list.iter().map(|l| (l.clone(), None)).collect(),
    };
    let mut seen = Vec::new();
    for (fname, detected) in wanted.into_iter().chain(mapped_features.iter().map(|m| (m.clone(), None))) {
        if seen.contains(&fname) {
            continue;
        }
        seen.push(fname.clone());
        let channels = match maps.remove(&format!("feature.{fname}")) {
            Some(c) => c,
            None => match detected.or_else(|| resolve_feature_channels(&names, &fname)) {
                Some(c) => c,
                None => {
                    return Err(err(
                        path,
                        channel_names,
                        format!(
                            "feature {fname:?} has no channels (looked for {fname}.* and {fname}); map it with --map feature.{fname}=CH,..."
                        ),
                    ));
                }
            },
        };
        let variance = match maps.remove(&format!("feature-var.{fname}")) {
            Some(v) => Some(v),
            None => find_variance(&names, &channels),
        };
        if let Some(v) = &variance
            && v.len() != channels.len()
        {
            return Err(err(
                path,
                channel_names,
                format!("feature {fname}: {} variance channels for {} channels", v.len(), channels.len()),
            ));
        }
        features.push(FeatureRole { name: fname, channels, variance });
    }

    // Layers.
    let mut layers = Vec::new();
    let mapped_layers: Vec<String> = maps.keys().filter_map(|k| k.strip_prefix("layer.")).map(str::to_string).collect();
    let (wanted, explicit): (Vec<String>, bool) = match &opts.layers {
        Selection::None => (Vec::new(), false),
        Selection::Auto => (AUTO_LAYERS.iter().map(|s| s.to_string()).collect(), false),
        Selection::List(l) => (l.clone(), true),
    };
    let mut auto_layers = Vec::new();
    for lname in wanted.iter().chain(&mapped_layers) {
        let is_explicit = explicit || mapped_layers.contains(lname);
        let channels = match maps.remove(&format!("layer.{lname}")) {
            Some(c) => c,
            None => {
                let ch: Vec<String> = colour.iter().map(|c| format!("{lname}.{}", leaf(c))).collect();
                if names.all_present(&ch) {
                    ch
                } else if is_explicit {
                    return Err(err(
                        path,
                        channel_names,
                        format!(
                            "layer {lname:?}: channels {} not found; map them with --map layer.{lname}=...",
                            ch.join(",")
                        ),
                    ));
                } else {
                    continue;
                }
            }
        };
        check_count(&format!("layer {lname}"), &channels)?;
        let variance = match maps.remove(&format!("layer-var.{lname}")) {
            Some(v) => Some(v),
            None => find_variance(&names, &channels),
        };
        match variance {
            Some(v) => {
                check_count(&format!("variance of layer {lname}"), &v)?;
                let l = LayerRole { name: lname.clone(), channels, variance: VarianceRole::Sample(v) };
                if is_explicit { layers.push(l) } else { auto_layers.push(l) }
            }
            None if is_explicit => {
                return Err(err(
                    path,
                    channel_names,
                    format!(
                        "layer {lname:?} has no variance channels (e.g. var.{lname}.R); map them with --map layer-var.{lname}=..."
                    ),
                ));
            }
            None => notes.push(format!("layer {lname} found but it has no variance; layers not used")),
        }
    }
    if !auto_layers.is_empty() {
        if auto_layers.len() == AUTO_LAYERS.len() {
            layers.extend(auto_layers);
        } else {
            notes.push(format!(
                "only {} of the light layers {} found; layers not used",
                auto_layers.iter().map(|l| l.name.as_str()).collect::<Vec<_>>().join(","),
                AUTO_LAYERS.join("+")
            ));
        }
    }
    if opts.layers == Selection::None {
        let present: Vec<&str> = AUTO_LAYERS
            .iter()
            .copied()
            .filter(|l| colour.iter().all(|c| names.has(&format!("{l}.{}", leaf(c)))))
            .collect();
        if !present.is_empty() {
            notes.push(format!(
                "light layers {} present but not used (--layers auto filters them separately)",
                present.join(",")
            ));
        }
    }
    if let Some(k) = maps.keys().next() {
        return Err(err(path, channel_names, format!("--map role {k:?} is not used: {MAP_HELP}")));
    }
    Ok(ChannelRoles { colour, variance, features, layers, notes })
}

/// The name a detected feature goes by: its channel group (`albedo`, `N`), or
/// the channel itself for a single root channel (`Z`).
fn group_name(channels: &[String]) -> String {
    let g = group_of(&channels[0]);
    if g.is_empty() { channels[0].clone() } else { g.to_string() }
}

impl ChannelRoles {
    /// The role of each channel, for `nldenoise info`.
    pub fn role_of(&self, channel: &str) -> String {
        let pos = |v: &[String]| v.iter().position(|c| c == channel);
        if pos(&self.colour).is_some() {
            return "colour (denoised)".into();
        }
        match &self.variance {
            VarianceRole::Sample(v) if pos(v).is_some() => {
                return "colour variance (sample variance of the mean)".into();
            }
            VarianceRole::Halves(a, b) if pos(a).is_some() || pos(b).is_some() => {
                return "colour half buffer (variance = (A-B)^2/4)".into();
            }
            _ => {}
        }
        for f in &self.features {
            if pos(&f.channels).is_some() {
                return format!("feature {}", f.name);
            }
            if f.variance.as_deref().and_then(pos).is_some() {
                return format!("feature {} variance", f.name);
            }
        }
        for l in &self.layers {
            if pos(&l.channels).is_some() {
                return format!("light layer {} (denoised)", l.name);
            }
            if let VarianceRole::Sample(v) = &l.variance
                && pos(v).is_some()
            {
                return format!("light layer {} variance", l.name);
            }
        }
        "carried unchanged".into()
    }

    /// Channels whose values the denoiser replaces.
    pub fn outputs(&self) -> Vec<String> {
        let mut v = self.colour.clone();
        for l in &self.layers {
            v.extend(l.channels.iter().cloned());
        }
        v
    }

    /// The kinds of input these roles give the filter (for the halo).
    pub fn shape(&self) -> crate::filter::InputShape {
        crate::filter::InputShape {
            feature_has_variance: self.features.iter().map(|f| f.variance.is_some()).collect(),
            layers: self.layers.len(),
        }
    }

    /// Every channel the filter reads.
    pub fn inputs_channels(&self) -> Vec<String> {
        let mut v = self.colour.clone();
        let var = |v: &VarianceRole| match v {
            VarianceRole::Sample(s) => s.clone(),
            VarianceRole::Halves(a, b) => a.iter().chain(b).cloned().collect(),
        };
        v.extend(var(&self.variance));
        for f in &self.features {
            v.extend(f.channels.iter().cloned());
            v.extend(f.variance.iter().flatten().cloned());
        }
        for l in &self.layers {
            v.extend(l.channels.iter().cloned());
            v.extend(var(&l.variance));
        }
        v
    }

    /// Build the filter's inputs from a frame held in memory.
    pub fn inputs(&self, frame: &Frame) -> FrameInputs {
        self.inputs_with(|n| frame.plane(n).expect("role channels exist"))
    }

    /// Build the filter's inputs, getting each channel's plane from `plane`.
    pub fn inputs_with(&self, mut plane: impl FnMut(&str) -> crate::image::Plane) -> FrameInputs {
        let mut planes = |names: &[String]| names.iter().map(|n| plane(n)).collect::<Vec<_>>();
        let colour_values = planes(&self.colour);
        let var = |v: &VarianceRole, planes: &mut dyn FnMut(&[String]) -> Vec<crate::image::Plane>| match v {
            VarianceRole::Sample(s) => VarianceSource::Sample(planes(s)),
            VarianceRole::Halves(a, b) => VarianceSource::Halves { a: planes(a), b: planes(b) },
        };
        let colour_var = var(&self.variance, &mut planes);
        let features = self
            .features
            .iter()
            .map(|f| Feature {
                name: f.name.clone(),
                values: planes(&f.channels),
                variance: f.variance.as_deref().map(&mut planes),
            })
            .collect();
        let layers = self
            .layers
            .iter()
            .map(|l| {
                let values = planes(&l.channels);
                Buffer { name: l.name.clone(), values, variance: var(&l.variance, &mut planes) }
            })
            .collect();
        FrameInputs {
            colour: Buffer { name: "beauty".into(), values: colour_values, variance: colour_var },
            features,
            layers,
        }
    }
}
