//! Frame sequences for batch runs: which frames to denoise, where each is
//! read and where it is written.
//!
//! A render farm writes a shot as one EXR per frame, named with a frame
//! number: `shot.1001.exr`, `shot.1002.exr`, ... A path names the whole
//! sequence with a frame pattern in its file name, in either of the two
//! spellings compositing and pipeline tools use:
//!
//! * `shot.####.exr`: a run of `#`, one per digit of zero padding;
//! * `shot.%04d.exr`: printf style (`%d` for no padding).
//!
//! [`plan`] turns the command line's inputs, output and optional frame list
//! into one [`Job`] per frame: a pattern input with a pattern output (or an
//! output folder), or several plain inputs with an output folder, or the
//! single input and output of a one-frame run. Frames come from a frame
//! list ([`parse_frames`]: `1001-1100`, `1001-1100x2`, `1001,1005`) or, without
//! one, from the files present that match the pattern ([`FramePattern::discover`]).
//! Every job is checked before any frame is filtered: no two jobs write the
//! same file.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Most digits of padding a frame pattern may ask for.
pub const MAX_PADDING: usize = 32;

/// Most frames one frame list may name (a guard against typos such as
/// `1-100000000`, which would otherwise allocate a job per frame).
pub const MAX_FRAMES: usize = 1_000_000;

/// A path with a frame-number pattern in its file name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePattern {
    /// The folder part of the path (may be empty: the current folder).
    dir: PathBuf,
    /// The file name before and after the pattern.
    prefix: String,
    suffix: String,
    /// Digits of zero padding (at least 1).
    width: usize,
}

impl FramePattern {
    /// The pattern in `path`'s file name, or `None` when it has none. A
    /// pattern is a run of `#` or a printf `%d` / `%0Nd`; more than one in
    /// the file name, a pattern in a folder name, or a file name that is
    /// not UTF-8 but has a `#` or `%` is an error.
    pub fn parse(path: &Path) -> Result<Option<FramePattern>> {
        let bad = |why: &str| Error::InvalidParameter(format!("{}: {why}", path.display()));
        if let Some(parent) = path.parent()
            && parent.components().any(|c| token(&c.as_os_str().to_string_lossy()).is_some())
        {
            return Err(bad("a frame pattern (#### or %04d) must be in the file name, not in a folder name"));
        }
        let Some(name) = path.file_name() else { return Ok(None) };
        let Some(name) = name.to_str() else {
            let lossy = name.to_string_lossy();
            return if lossy.contains('#') || lossy.contains('%') {
                Err(bad("a file name with a frame pattern must be valid UTF-8"))
            } else {
                Ok(None)
            };
        };
        let Some((start, end, width)) = token(name) else { return Ok(None) };
        if token(&name[end..]).is_some() {
            return Err(bad("more than one frame pattern in the file name"));
        }
        if width > MAX_PADDING {
            return Err(bad(&format!("a frame pattern of {width} digits (at most {MAX_PADDING})")));
        }
        Ok(Some(FramePattern {
            dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
            prefix: name[..start].to_string(),
            suffix: name[end..].to_string(),
            width,
        }))
    }

    /// The file name of frame `frame` (zero-padded to the pattern's width;
    /// a negative frame gets its sign before the padding: `-001`).
    pub fn file_name(&self, frame: i64) -> String {
        format!("{}{}{}", self.prefix, self.number(frame), self.suffix)
    }

    /// The path of frame `frame`.
    pub fn path(&self, frame: i64) -> PathBuf {
        self.dir.join(self.file_name(frame))
    }

    fn number(&self, frame: i64) -> String {
        format!("{frame:0w$}", w = self.width + usize::from(frame < 0))
    }

    /// The frames whose files exist in the pattern's folder, in increasing
    /// order: every file name that is the pattern with a frame number
    /// spelled exactly as [`FramePattern::file_name`] spells it.
    pub fn discover(&self) -> Result<Vec<i64>> {
        let dir = if self.dir.as_os_str().is_empty() { Path::new(".") } else { &self.dir };
        let io = |source| Error::Io { path: dir.to_path_buf(), source };
        let mut frames = BTreeSet::new();
        for entry in std::fs::read_dir(dir).map_err(io)? {
            let entry = entry.map_err(io)?;
            let name = entry.file_name();
            let Some(name) = name.to_str() else { continue };
            let Some(middle) = name.strip_prefix(&self.prefix).and_then(|m| m.strip_suffix(&self.suffix)) else {
                continue;
            };
            let digits = middle.strip_prefix('-').unwrap_or(middle);
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                continue;
            }
            if let Ok(frame) = middle.parse::<i64>()
                && self.number(frame) == middle
                && !entry.file_type().map_err(io)?.is_dir()
            {
                frames.insert(frame);
            }
        }
        Ok(frames.into_iter().collect())
    }
}

/// The first frame pattern in `s`: its byte range and padding width.
fn token(s: &str) -> Option<(usize, usize, usize)> {
    let b = s.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'#' {
            let end = i + b[i..].iter().take_while(|&&c| c == b'#').count();
            return Some((i, end, end - i));
        }
        if b[i] == b'%' {
            // `%d`, or `%0Nd` with N digits.
            let digits = b[i + 1..].iter().take_while(|c| c.is_ascii_digit()).count();
            let at = i + 1 + digits;
            if at < b.len() && b[at] == b'd' && (digits == 0 || b[i + 1] == b'0') {
                let width = if digits == 0 { 1 } else { s[i + 1..at].parse().unwrap_or(usize::MAX) };
                return Some((i, at + 1, width.max(1)));
            }
        }
        i += 1;
    }
    None
}

/// The frames of a frame list, in increasing order without repeats:
/// comma-separated items `N`, `A-B` (`A` to `B` inclusive) or `A-BxS`
/// (every `S`-th frame from `A`), e.g. `1001-1100x2,1200`. Frames may be
/// negative (`-10--1`). At most [`MAX_FRAMES`] frames.
pub fn parse_frames(spec: &str) -> Result<Vec<i64>> {
    let bad = |why: String| Error::InvalidParameter(format!("--frames {spec:?}: {why}"));
    let number = |s: &str| s.trim().parse::<i64>().map_err(|_| bad(format!("{:?} is not a frame number", s.trim())));
    let mut frames = BTreeSet::new();
    for item in spec.split(',') {
        let item = item.trim();
        if item.is_empty() {
            return Err(bad("an empty item".into()));
        }
        let (range, step) = match item.split_once('x') {
            Some((r, s)) => (r, number(s)?),
            None => (item, 1),
        };
        // The range's dash is the first one after a digit (a leading dash is a sign).
        let dash = range.char_indices().skip(1).find(|&(i, c)| c == '-' && range.as_bytes()[i - 1].is_ascii_digit());
        let (first, last) = match dash {
            Some((i, _)) => (number(&range[..i])?, number(&range[i + 1..])?),
            None if item.contains('x') => return Err(bad(format!("{item:?}: a step needs a range (A-BxS)"))),
            None => {
                let n = number(range)?;
                (n, n)
            }
        };
        if last < first {
            return Err(bad(format!("{item:?}: the range ends before it starts")));
        }
        if step < 1 {
            return Err(bad(format!("{item:?}: the step must be at least 1")));
        }
        let count = (last.abs_diff(first) / step as u64).saturating_add(1);
        if count > (MAX_FRAMES - frames.len()) as u64 {
            return Err(bad(format!("more than {MAX_FRAMES} frames")));
        }
        frames.extend((0..count as i64).map(|k| first + k * step));
    }
    Ok(frames.into_iter().collect())
}

/// One frame of a run: where it is read and where it is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Job {
    /// The frame number, for a sequence given by a pattern.
    pub frame: Option<i64>,
    /// The noisy frame.
    pub input: PathBuf,
    /// Where its denoised frame goes.
    pub output: PathBuf,
}

/// The jobs of a run of `inputs` to `output`, checked before any frame is
/// filtered:
///
/// * one input without a pattern (or a file that exists, whatever its
///   name): one job, to the file `output` (as a single run has always
///   written it: a folder there is the writer's error);
/// * one input with a frame pattern: one job per frame of `frames` (a frame
///   list, see [`parse_frames`]), or per file matching the pattern when
///   `frames` is `None`; `output` is a pattern (its own padding) or a folder
///   (the input's file names);
/// * several inputs (a shell's glob): one job each, into the folder `output`
///   under the input's file name.
///
/// For a batch, `output` is a folder when it exists as one or ends with a
/// path separator, and a folder must exist. An error names the argument at fault;
/// two jobs writing the same file are an error.
pub fn plan(inputs: &[PathBuf], output: &Path, frames: Option<&str>) -> Result<Vec<Job>> {
    let bad = |why: String| Error::InvalidParameter(why);
    // A file that exists is itself, even with a `#` or `%d` in its name.
    let pattern_of = |p: &Path| if p.is_file() { Ok(None) } else { FramePattern::parse(p) };
    let out_text = output.as_os_str().to_string_lossy();
    let out_is_dir = output.is_dir() || out_text.ends_with('/') || out_text.ends_with(std::path::MAIN_SEPARATOR);
    // For a batch: the output folder must exist (a single frame's output is
    // a file path, whose faults the writer reports).
    let batch_folder = || {
        if out_is_dir && !output.is_dir() {
            return Err(bad(format!("{}: the output folder does not exist", output.display())));
        }
        Ok(out_is_dir)
    };
    let into_dir = |input: &Path, name: Option<String>| -> Result<PathBuf> {
        let name = match name {
            Some(n) => n.into(),
            None => {
                input.file_name().ok_or_else(|| bad(format!("{}: not a file name", input.display())))?.to_os_string()
            }
        };
        Ok(output.join(name))
    };
    let jobs = match inputs {
        [] => return Err(bad("no input given".into())),
        [input] => match pattern_of(input)? {
            None => {
                if frames.is_some() {
                    return Err(bad(format!(
                        "--frames needs a frame pattern (#### or %04d) in the input's file name, not {}",
                        input.display()
                    )));
                }
                if !input.is_file() && pattern_of(output)?.is_some() {
                    return Err(bad(format!(
                        "the output {} has a frame pattern but the input {} has none",
                        output.display(),
                        input.display()
                    )));
                }
                vec![Job { frame: None, input: input.clone(), output: output.to_path_buf() }]
            }
            Some(pattern) => {
                let frames = match frames {
                    Some(spec) => parse_frames(spec)?,
                    None => pattern.discover()?,
                };
                if frames.is_empty() {
                    return Err(bad(format!("{}: no file matches this frame pattern", input.display())));
                }
                let out_pattern = FramePattern::parse(output)?;
                let out_is_dir = batch_folder()?;
                if out_pattern.is_none() && !out_is_dir {
                    return Err(bad(format!(
                        "the input {} is a frame sequence: the output {} must be a frame pattern (#### or %04d) or an existing folder",
                        input.display(),
                        output.display()
                    )));
                }
                let mut jobs = Vec::with_capacity(frames.len());
                for f in frames {
                    let out = match &out_pattern {
                        Some(p) => p.path(f),
                        None => into_dir(input, Some(pattern.file_name(f)))?,
                    };
                    jobs.push(Job { frame: Some(f), input: pattern.path(f), output: out });
                }
                jobs
            }
        },
        several => {
            if let Some(p) = several.iter().find(|p| matches!(pattern_of(p), Ok(Some(_)))) {
                return Err(bad(format!("{}: a frame pattern must be the only input", p.display())));
            }
            if frames.is_some() {
                return Err(bad("--frames needs a single input with a frame pattern (#### or %04d)".into()));
            }
            if !batch_folder()? {
                return Err(bad(format!(
                    "{} inputs: the output {} must be an existing folder",
                    several.len(),
                    output.display()
                )));
            }
            several
                .iter()
                .map(|input| Ok(Job { frame: None, input: input.clone(), output: into_dir(input, None)? }))
                .collect::<Result<Vec<_>>>()?
        }
    };
    let mut seen: HashMap<&Path, &Path> = HashMap::new();
    for job in &jobs {
        if let Some(first) = seen.insert(&job.output, &job.input) {
            return Err(bad(format!(
                "{} and {} would both be written to {}",
                first.display(),
                job.input.display(),
                job.output.display()
            )));
        }
    }
    Ok(jobs)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(s: &str) -> FramePattern {
        FramePattern::parse(Path::new(s)).unwrap().unwrap()
    }

    #[test]
    fn patterns_in_both_spellings() {
        assert_eq!(pattern("r/shot.####.exr").path(1001), Path::new("r/shot.1001.exr"));
        assert_eq!(pattern("r/shot.####.exr").path(7), Path::new("r/shot.0007.exr"));
        assert_eq!(pattern("shot.%04d.exr").path(42), Path::new("shot.0042.exr"));
        assert_eq!(pattern("shot_%d.exr").path(42), Path::new("shot_42.exr"));
        assert_eq!(pattern("shot.#.exr").path(12345), Path::new("shot.12345.exr"));
        assert_eq!(pattern("s.###.exr").path(-5), Path::new("s.-005.exr"));
        assert_eq!(FramePattern::parse(Path::new("r/shot.1001.exr")).unwrap(), None);
        // A percent sign that is not a frame pattern.
        assert_eq!(FramePattern::parse(Path::new("100%.exr")).unwrap(), None);
        assert_eq!(FramePattern::parse(Path::new("a%4d.exr")).unwrap(), None);
    }

    #[test]
    fn rejected_patterns() {
        let many = format!("a.{}.exr", "#".repeat(70_000));
        for p in [
            "a.##.##.exr",
            "a.%04d.#.exr",
            "r###/a.exr",
            "a.%033d.exr",
            "a.%099999999999d.exr",
            "a.%0999999999999999999999d.exr",
            &many,
        ] {
            assert!(FramePattern::parse(Path::new(p)).is_err(), "{p}");
        }
    }

    #[test]
    fn frame_lists() {
        assert_eq!(parse_frames("1001-1004").unwrap(), vec![1001, 1002, 1003, 1004]);
        assert_eq!(parse_frames("1-9x4").unwrap(), vec![1, 5, 9]);
        assert_eq!(parse_frames("1-10x4").unwrap(), vec![1, 5, 9]);
        assert_eq!(parse_frames("5, 1,3-4,5").unwrap(), vec![1, 3, 4, 5]);
        assert_eq!(parse_frames("-3--1,-7").unwrap(), vec![-7, -3, -2, -1]);
        assert_eq!(parse_frames("-2-1").unwrap(), vec![-2, -1, 0, 1]);
        for bad in ["", "1,", "a", "5-1", "1-5x0", "1x2", "1-2-3", "0-1000000", "1-5x-1"] {
            assert!(parse_frames(bad).is_err(), "{bad:?}");
        }
        assert_eq!(parse_frames("0-999999").unwrap().len(), MAX_FRAMES);
    }

    proptest::proptest! {
        /// Any frame list either parses to sorted distinct frames or is an
        /// error; never a panic.
        #[test]
        fn frame_lists_never_panic(spec in "[0-9x, -]{0,24}") {
            if let Ok(frames) = parse_frames(&spec) {
                proptest::prop_assert!(frames.windows(2).all(|w| w[0] < w[1]));
                proptest::prop_assert!(frames.len() <= MAX_FRAMES);
            }
        }

        /// Any file name either has no pattern, one pattern, or an error;
        /// a pattern's frame numbers read back as the frames they spell.
        #[test]
        fn patterns_never_panic_and_round_trip(name in "[a.#%0-9d]{0,16}", frame in proptest::num::i64::ANY) {
            if let Ok(Some(p)) = FramePattern::parse(Path::new(&name)) {
                let number = p.number(frame);
                proptest::prop_assert_eq!(number.parse::<i64>().unwrap(), frame);
                proptest::prop_assert!(p.file_name(frame).starts_with(&p.prefix));
            }
        }
    }

    #[test]
    fn discovery_matches_the_spelling_exactly() {
        let dir = tempfile::tempdir().unwrap();
        for name in
            ["s.0001.exr", "s.0010.exr", "s.12345.exr", "s.00002.exr", "s.0003.exr.tmp", "s.abcd.exr", "t.0004.exr"]
        {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        std::fs::create_dir(dir.path().join("s.0005.exr")).unwrap();
        let p = FramePattern::parse(&dir.path().join("s.####.exr")).unwrap().unwrap();
        assert_eq!(p.discover().unwrap(), vec![1, 10, 12345]);
    }

    #[test]
    fn plans() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let pb = |s: &str| d.join(s);
        for f in [1, 2, 3] {
            std::fs::write(pb(&format!("in.{f:04}.exr")), b"").unwrap();
        }
        std::fs::create_dir(pb("out")).unwrap();
        // One frame, as before: the output is the path given, even a folder
        // (which the writer then refuses, naming it).
        let one = plan(&[pb("a.exr")], &pb("b.exr"), None).unwrap();
        assert_eq!(one, vec![Job { frame: None, input: pb("a.exr"), output: pb("b.exr") }]);
        assert_eq!(plan(&[pb("a.exr")], &pb("out"), None).unwrap()[0].output, pb("out"));
        // A pattern: discovered frames, or a list; to a pattern or a folder.
        let seq = plan(&[pb("in.####.exr")], &pb("out/o.%02d.exr"), None).unwrap();
        assert_eq!(seq.iter().map(|j| j.frame.unwrap()).collect::<Vec<_>>(), vec![1, 2, 3]);
        assert_eq!((seq[1].input.clone(), seq[1].output.clone()), (pb("in.0002.exr"), pb("out/o.02.exr")));
        let listed = plan(&[pb("in.####.exr")], &pb("out"), Some("3,7")).unwrap();
        assert_eq!(listed[1], Job { frame: Some(7), input: pb("in.0007.exr"), output: pb("out/in.0007.exr") });
        // Files that exist are taken as they are, `#` or not.
        std::fs::write(pb("take#1.exr"), b"").unwrap();
        std::fs::write(pb("take#2.exr"), b"").unwrap();
        let literal = plan(&[pb("take#1.exr")], &pb("take#1_den.exr"), None).unwrap();
        assert_eq!(literal[0].output, pb("take#1_den.exr"));
        assert_eq!(plan(&[pb("take#1.exr"), pb("take#2.exr")], &pb("out"), None).unwrap().len(), 2);
        // Several inputs into a folder.
        let many = plan(&[pb("in.0001.exr"), pb("in.0002.exr")], &pb("out"), None).unwrap();
        assert_eq!(many[1].output, pb("out/in.0002.exr"));
        // Errors, before anything runs.
        let err = |i: &[&str], o: &str, f: Option<&str>| {
            plan(&i.iter().map(|s| pb(s)).collect::<Vec<_>>(), &pb(o), f).unwrap_err().to_string()
        };
        assert!(err(&["a.exr"], "b.exr", Some("1-3")).contains("--frames needs a frame pattern"));
        assert!(err(&["a.exr"], "b.####.exr", None).contains("has a frame pattern but the input"));
        assert!(err(&["in.####.exr"], "b.exr", None).contains("must be a frame pattern"));
        assert!(err(&["x.####.exr"], "out", None).contains("no file matches"));
        assert!(err(&["a.exr", "b.exr"], "b.exr", None).contains("must be an existing folder"));
        assert!(err(&["a.exr", "in.####.exr"], "out", None).contains("must be the only input"));
        assert!(err(&["a.exr", "b.exr"], "missing/", None).contains("does not exist"));
        assert!(err(&["in.####.exr"], "out/same.exr/", None).contains("does not exist"));
        assert!(err(&["a.exr", "sub/a.exr"], "out", None).contains("would both be written to"));
    }
}
