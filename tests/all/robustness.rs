//! The command line under bad conditions: malformed files, missing inputs,
//! parameter edges, write faults (missing or read-only folder, full disk,
//! killed mid-frame), input == output, NaN reporting and thousands of
//! channels. Exit code 1 with a message naming the file, never 101, never a
//! partial output, never a modified input.

use std::ffi::{OsStr, OsString};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use nldenoise::exrio::{self, Channel, Frame, OutputCompression, WriteOptions};
use nldenoise::geom::Rect;

use crate::common::Rng;

fn exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_nldenoise"))
}

fn run<S: AsRef<OsStr>>(args: &[S]) -> Output {
    Command::new(exe()).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A small frame with colour, variance, albedo; `bad` pixels get NaN in R.
fn small_frame(w: usize, h: usize, bad: &[(i64, i64)]) -> Frame {
    let dw = Rect::from_origin_size(0, 0, w, h);
    let mut rng = Rng::new(77);
    let mut ch = Vec::new();
    for name in ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "var.B", "var.G", "var.R"] {
        let mut v: Vec<f32> = (0..dw.area()).map(|_| 0.1 + rng.uniform()).collect();
        if name == "R" {
            for &(x, y) in bad {
                v[y as usize * w + x as usize] = f32::NAN;
            }
        }
        if name.starts_with("var") {
            v.iter_mut().for_each(|x| *x *= 0.01);
        }
        ch.push(Channel::from_f32(name, v));
    }
    Frame::new(dw, ch)
}

fn write(dir: &Path, name: &str, frame: &Frame) -> PathBuf {
    let p = dir.join(name);
    exrio::write_frame(&p, frame, &WriteOptions::default()).unwrap();
    p
}

/// No temporary files left in `dir`.
fn no_temporaries(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".nldenoise-"))
        .collect();
    assert!(left.is_empty(), "temporary files left: {left:?}");
}

const FAST: [&str; 4] = ["--search-radius", "3", "--patch-radius", "1"];

fn denoise_args(input: &Path, output: &Path, extra: &[&str]) -> Vec<OsString> {
    let mut v: Vec<OsString> = vec!["denoise".into(), input.into(), "-o".into(), output.into()];
    for pair in FAST.chunks(2) {
        if !extra.contains(&pair[0]) {
            v.extend(pair.iter().map(OsString::from));
        }
    }
    v.extend(extra.iter().map(OsString::from));
    v
}

/// A failure as the brief demands: exit 1, the message names `needle`, no panic.
fn assert_clean_failure(o: &Output, needle: &str, case: &str) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{case}: exit status {:?}, stderr: {e}", o.status);
    assert!(e.contains(needle), "{case}: stderr should name {needle:?}: {e}");
    assert!(!e.contains("panicked"), "{case}: {e}");
}

#[test]
fn malformed_files_fail_with_exit_1_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(dir.path(), "good.exr", &small_frame(20, 40, &[]));
    let bytes = std::fs::read(&good).unwrap();
    let mut rng = Rng::new(1);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty", Vec::new()),
        ("truncated header", bytes[..100].to_vec()),
        ("truncated in the offset table", bytes[..bytes.len() / 4].to_vec()),
        ("truncated mid-chunk", bytes[..bytes.len() * 3 / 4].to_vec()),
        ("random", (0..4000).map(|_| rng.next_u64() as u8).collect()),
        ("wrong magic", [b"\x89PNG".as_slice(), &bytes[4..]].concat()),
    ];
    let out = dir.path().join("out.exr");
    for (case, b) in cases {
        let input = dir.path().join(format!("{}.exr", case.replace(' ', "_")));
        std::fs::write(&input, &b).unwrap();
        let name = input.file_name().unwrap().to_str().unwrap();
        for extra in [&[][..], &["--tile-size", "0"][..], &["--tile-size", "1", "--threads", "3"][..]] {
            let o = run(&denoise_args(&input, &out, extra));
            assert_clean_failure(&o, name, &format!("{case} {extra:?}"));
            assert!(!out.exists(), "{case}: output written");
        }
        let o = run(&[OsStr::new("info"), input.as_os_str()]);
        assert_clean_failure(&o, name, &format!("info {case}"));
        assert_eq!(std::fs::read(&input).unwrap(), b, "input modified");
    }
    // Not a file at all.
    let o = run(&denoise_args(dir.path(), &out, &[]));
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let o = run(&denoise_args(&dir.path().join("missing.exr"), &out, &[]));
    assert_clean_failure(&o, "missing.exr", "missing input");
    no_temporaries(dir.path());
}

#[test]
fn missing_channels_list_what_was_found_and_how_to_map() {
    let dir = tempfile::tempdir().unwrap();
    let dw = Rect::from_origin_size(0, 0, 8, 8);
    let only_depth =
        Frame::new(dw, vec![Channel::from_f32("Z", vec![1.0; 64]), Channel::from_f32("alpha", vec![1.0; 64])]);
    let depth = write(dir.path(), "depth.exr", &only_depth);
    let full = write(dir.path(), "full.exr", &small_frame(16, 16, &[]));
    let out = dir.path().join("out.exr");
    for (input, extra, needle) in [
        (&depth, vec![], "no colour channels"),
        (&full, vec!["--map", "feature.foo=nope.X,nope.Y"], "nope.X"),
        (&full, vec!["--map", "A=R,G,B", "--map", "B=var.R,var.G"], "B"),
        (&full, vec!["--variance", "halves"], "half"),
        (&full, vec!["--features", "normal"], "normal"),
        (&full, vec!["--layers", "direct"], "direct"),
    ] {
        let o = run(&denoise_args(input, &out, &extra));
        let case = format!("{extra:?}");
        assert_clean_failure(&o, needle, &case);
        let e = stderr(&o);
        assert!(e.contains("channels found:"), "{case}: {e}");
        assert!(e.contains("--map ROLE="), "{case}: the error says how to map: {e}");
        assert!(e.contains(input.file_name().unwrap().to_str().unwrap()), "{case}: {e}");
        assert!(!out.exists());
    }
    let e = stderr(&run(&denoise_args(&depth, &out, &[])));
    assert!(e.contains("Z, alpha"), "channels listed: {e}");
}

#[test]
fn parameter_edges_work_or_fail_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(dir.path(), "in.exr", &small_frame(24, 18, &[]));
    let out = dir.path().join("out.exr");
    let reference = dir.path().join("whole.exr");
    // Accepted edges: each must produce a finite output.
    for extra in [
        &["--search-radius", "0"][..],
        &["--search-radius", "40", "--patch-radius", "12"],
        &["--strength", "0"],
        &["--tile-size", "1"],
        &["--threads", "64"],
        &["--tile-size", "100000"],
        &["--patch-radius", "0", "--variance-prefilter", "0", "--feature-prefilter-radius", "0"],
    ] {
        let o = run(&denoise_args(&input, &out, extra));
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let f = exrio::read_frame(&out).unwrap();
        assert!(f.plane("R").unwrap().data().iter().all(|v| v.is_finite()), "{extra:?}");
    }
    // Tile size 1 with many threads is the whole frame, bit for bit.
    assert!(run(&denoise_args(&input, &reference, &["--tile-size", "0"])).status.success());
    assert!(run(&denoise_args(&input, &out, &["--tile-size", "1", "--threads", "5"])).status.success());
    let (a, b) = (exrio::read_frame(&out).unwrap(), exrio::read_frame(&reference).unwrap());
    for c in ["R", "G", "B"] {
        let bits = |f: &Frame| f.plane(c).unwrap().data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b), "{c}");
    }
    // Refused: each names the parameter, or the minimum memory.
    std::fs::remove_file(&out).unwrap();
    for (extra, needle) in [
        (&["--memory-limit", "1K"][..], "at least"),
        (&["--memory-limit", "1K", "--tile-size", "0"], "memory limit"),
        (&["--strength=-1"], "strength"),
        (&["--strength", "NaN"], "strength"),
        (&["--search-radius", "5000"], "search radius"),
        (&["--tau", "0"], "tau"),
    ] {
        let o = run(&denoise_args(&input, &out, extra));
        assert_clean_failure(&o, needle, &format!("{extra:?}"));
        assert!(!out.exists());
    }
    // The minimum the error states is enough.
    let e = stderr(&run(&denoise_args(&input, &out, &["--memory-limit", "1K"])));
    let needed: String =
        e.split("at least ").nth(1).unwrap().chars().take_while(|c| c.is_ascii_digit()).collect::<String>();
    let o = run(&denoise_args(&input, &out, &["--memory-limit", &needed]));
    assert!(o.status.success(), "the stated minimum {needed} must work: {}", stderr(&o));
    // Usage errors are clap's exit 2.
    let o = run(&denoise_args(&input, &out, &["--threads", "-1"]));
    assert_eq!(o.status.code(), Some(2));
    no_temporaries(dir.path());
}

#[test]
fn unwritable_outputs_fail_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(dir.path(), "in.exr", &small_frame(16, 16, &[]));
    let before = std::fs::read(&input).unwrap();
    let a_file = dir.path().join("plain");
    std::fs::write(&a_file, b"x").unwrap();
    let ro = dir.path().join("readonly");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::os::unix::fs::PermissionsExt::from_mode(0o555)).unwrap();
    // Root ignores folder permissions; /proc refuses new files for everyone.
    let read_only_dir =
        if std::fs::write(ro.join("probe"), b"").is_err() { ro.clone() } else { PathBuf::from("/proc") };
    for (out, case) in [
        (dir.path().join("no/such/folder/out.exr"), "missing folder"),
        (a_file.join("out.exr"), "parent is a file"),
        (read_only_dir.join("out.exr"), "read-only folder"),
        (dir.path().to_path_buf(), "output is a folder"),
    ] {
        for extra in [&[][..], &["--tile-size", "0"]] {
            let o = run(&denoise_args(&input, &out, extra));
            assert_clean_failure(&o, out.to_str().unwrap(), &format!("{case} {extra:?}"));
        }
        assert!(!out.is_file(), "{case}");
    }
    assert_eq!(std::fs::read(&input).unwrap(), before);
    no_temporaries(dir.path());
}

/// Run the CLI with a file size limit: writes beyond `bytes` fail with EFBIG,
/// as on a full disk (SIGXFSZ ignored so the write returns the error).
fn run_with_file_limit(args: &[OsString], bytes: u64) -> Output {
    let mut cmd = Command::new(exe());
    cmd.args(args);
    // SAFETY: only async-signal-safe calls (setrlimit, signal) between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit { rlim_cur: bytes, rlim_max: bytes };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    cmd.output().unwrap()
}

#[test]
fn a_full_disk_leaves_no_output_and_names_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(dir.path(), "in.exr", &small_frame(64, 64, &[]));
    let before = std::fs::read(&input).unwrap();
    let out = dir.path().join("out.exr");
    for limit in [0u64, 1000, 40_000] {
        for extra in [&["--compression", "none"][..], &["--compression", "none", "--tile-size", "0"]] {
            let o = run_with_file_limit(&denoise_args(&input, &out, extra), limit);
            assert_clean_failure(&o, out.to_str().unwrap(), &format!("limit {limit} {extra:?}"));
            assert!(!out.exists(), "limit {limit}: partial output");
            no_temporaries(dir.path());
        }
    }
    assert_eq!(std::fs::read(&input).unwrap(), before);
    // The same run with room succeeds.
    let o = run_with_file_limit(&denoise_args(&input, &out, &["--compression", "none"]), 10 << 20);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Run `denoise INPUT -o OUTPUT` slowly (r = 10, tiles of 32, one thread)
/// and send it `signal` once a temporary output whose name holds `part`
/// appears in `out_dir`; returns its exit status.
fn signal_while_writing(
    input: &Path,
    output: &Path,
    out_dir: &Path,
    part: &str,
    signal: i32,
) -> std::process::ExitStatus {
    let mut child = Command::new(exe())
        .args(["denoise".as_ref(), input.as_os_str(), "-o".as_ref(), output.as_os_str()])
        .args(["--search-radius", "10", "--tile-size", "32", "--threads", "1"])
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let writing = || {
        std::fs::read_dir(out_dir).unwrap().flatten().any(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.contains(".nldenoise-") && name.contains(part)
        })
    };
    while !writing() {
        assert!(t0.elapsed() < Duration::from_secs(60), "no temporary output for {part:?} appeared");
        assert!(child.try_wait().unwrap().is_none(), "finished before it could be signalled");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(100));
    assert!(child.try_wait().unwrap().is_none(), "finished before it could be signalled");
    // SAFETY: plain kill(2) of our own child.
    unsafe { libc::kill(child.id() as i32, signal) };
    child.wait().unwrap()
}

/// Start a slow denoise and signal it once its temporary output exists.
fn kill_mid_frame(signal: i32) -> (tempfile::TempDir, PathBuf, std::process::ExitStatus) {
    let dir = tempfile::tempdir().unwrap();
    // Large enough (several seconds of filtering) that the run cannot end before the signal.
    let input = write(dir.path(), "in.exr", &small_frame(800, 600, &[]));
    let out = dir.path().join("out.exr");
    let status = signal_while_writing(&input, &out, dir.path(), "", signal);
    assert!(!out.exists(), "a partial output appeared at the output path");
    assert!(exrio::read_frame(&input).is_ok(), "the input is intact");
    (dir, out, status)
}

#[test]
fn killed_mid_frame_leaves_no_output() {
    // SIGTERM (a farm preempting the job): no output, no temporary file.
    let (dir, _, status) = kill_mid_frame(libc::SIGTERM);
    assert_eq!(status.code(), Some(130), "{status:?}");
    no_temporaries(dir.path());
    // SIGKILL cannot be caught: still nothing at the output path.
    let (_dir, out, status) = kill_mid_frame(libc::SIGKILL);
    assert!(status.code().is_none());
    assert!(!out.exists());
}

#[test]
fn input_and_output_may_be_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let frame = small_frame(30, 20, &[]);
    for extra in [&[][..], &["--tile-size", "0"]] {
        let input = write(dir.path(), "in.exr", &frame);
        let separate = dir.path().join("separate.exr");
        assert!(run(&denoise_args(&input, &separate, extra)).status.success());
        let o = run(&denoise_args(&input, &input, extra));
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        assert_eq!(std::fs::read(&input).unwrap(), std::fs::read(&separate).unwrap(), "{extra:?}");
    }
    no_temporaries(dir.path());
}

#[test]
fn repaired_pixels_are_reported_at_verbose() {
    let dir = tempfile::tempdir().unwrap();
    let bad = [(3, 3), (10, 7), (11, 7)];
    let input = write(dir.path(), "nan.exr", &small_frame(24, 16, &bad));
    let out = dir.path().join("out.exr");
    for extra in [&["-v"][..], &["-v", "--tile-size", "0"], &["-v", "--tile-size", "5"]] {
        let o = run(&denoise_args(&input, &out, extra));
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(stderr(&o).contains("3 pixels had NaN"), "{extra:?}: {}", stderr(&o));
        let f = exrio::read_frame(&out).unwrap();
        assert!(f.plane("R").unwrap().data().iter().all(|v| v.is_finite()));
    }
}

#[test]
fn thousands_of_channels_are_carried() {
    let dir = tempfile::tempdir().unwrap();
    let dw = Rect::from_origin_size(0, 0, 6, 5);
    let mut frame = small_frame(6, 5, &[]);
    for i in 0..3000 {
        frame.set_channel(Channel::from_f32_as_half(format!("aov{i:04}"), &vec![(i % 1000) as f32; dw.area()]));
    }
    let input = dir.path().join("many.exr");
    exrio::write_frame(&input, &frame, &WriteOptions { compression: OutputCompression::Zips, ..Default::default() })
        .unwrap();
    let out = dir.path().join("out.exr");
    let o = run(&denoise_args(&input, &out, &[]));
    assert!(o.status.success(), "{}", stderr(&o));
    let back = exrio::read_frame(&out).unwrap();
    assert_eq!(back.channels.len(), 3009);
    assert_eq!(back.channel("aov2999").unwrap().to_f32()[0], 999.0);
    // A role error on such a file lists a bounded number of channels.
    let e = stderr(&run(&denoise_args(&input, &out, &["--map", "color=x,y,z"])));
    assert!(e.contains("3009 channels in all") && e.len() < 4000, "{}", e.len());
}

#[test]
fn an_interrupted_batch_keeps_its_finished_frames_only() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "s.0001.exr", &small_frame(30, 20, &[]));
    // Several seconds of filtering: the signal comes while it is written.
    write(dir.path(), "s.0002.exr", &small_frame(800, 600, &[]));
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let status = signal_while_writing(&dir.path().join("s.####.exr"), &out, &out, "s.0002", libc::SIGTERM);
    assert_eq!(status.code(), Some(130), "{status:?}");
    let left: Vec<String> =
        std::fs::read_dir(&out).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(left, ["s.0001.exr"], "only the finished frame stays");
    assert!(exrio::read_frame(&out.join("s.0001.exr")).is_ok());
}
