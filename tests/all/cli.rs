//! The command line end to end on the shipped fixture.

use std::path::{Path, PathBuf};

use assert_cmd::Command;
use nldenoise::exrio::{self, SampleKind};
use nldenoise::metrics;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

fn bin() -> Command {
    Command::cargo_bin("nldenoise").unwrap()
}

fn rel_mse(a: &exrio::Frame, r: &exrio::Frame) -> f64 {
    let ch = ["R", "G", "B"].map(|c| (a.plane(c).unwrap(), r.plane(c).unwrap()));
    metrics::compare(
        &ch.iter().map(|(x, _)| x.data()).collect::<Vec<_>>(),
        &ch.iter().map(|(_, y)| y.data()).collect::<Vec<_>>(),
    )
    .rel_mse
}

#[test]
fn denoise_improves_the_fixture_and_keeps_every_channel() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let input = fixture("cornell_0032spp.exr");
    let before = std::fs::read(&input).unwrap();
    bin()
        .args(["denoise"])
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .args(["--threads", "2", "--layers", "auto"])
        .assert()
        .success();
    assert_eq!(std::fs::read(&input).unwrap(), before, "the input must not be modified");
    let noisy = exrio::read_frame(&input).unwrap();
    let den = exrio::read_frame(&out).unwrap();
    let reference = exrio::read_frame(&fixture("cornell_ref.exr")).unwrap();
    assert_eq!(den.channel_names(), noisy.channel_names());
    let (n, d) = (rel_mse(&noisy, &reference), rel_mse(&den, &reference));
    assert!(d < 0.5 * n, "denoised relMSE {d} should be well below the noisy {n}");
    for name in ["A.R", "var.G", "albedo.B", "N.X", "Z", "Z_var"] {
        let (a, b) = (noisy.channel(name).unwrap(), den.channel(name).unwrap());
        assert_eq!(a.kind, b.kind, "{name}");
        assert_eq!(a.to_f32(), b.to_f32(), "{name} must be carried unchanged");
    }
    assert_eq!(den.channel("R").unwrap().kind, SampleKind::F32);
    // Layers were denoised and sum to the beauty.
    let sum: Vec<f32> = den
        .plane("direct.G")
        .unwrap()
        .data()
        .iter()
        .zip(den.plane("indirect.G").unwrap().data())
        .map(|(a, b)| a + b)
        .collect();
    assert_eq!(sum, den.plane("G").unwrap().into_vec());
}

#[test]
fn half_output_and_explicit_options() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("half.exr");
    bin()
        .arg("denoise")
        .arg(fixture("cornell_0032spp.exr"))
        .arg("-o")
        .arg(&out)
        .args([
            "--half",
            "--features",
            "albedo,N",
            "--layers",
            "none",
            "--variance",
            "halves",
            "--search-radius",
            "4",
            "--compression",
            "piz",
        ])
        .assert()
        .success();
    let den = exrio::read_frame(&out).unwrap();
    assert_eq!(den.channel("R").unwrap().kind, SampleKind::F16);
}

/// `--zip-level` reaches the writer, streaming or whole-frame
/// (`--tile-size 0`): the fastest and the smallest levels write the same
/// samples, the smallest in fewer bytes; a level out of range fails before
/// any output.
#[test]
fn zip_levels_write_the_same_samples() {
    let dir = tempfile::tempdir().unwrap();
    let write = |level: &str, tile: &str| {
        let out = dir.path().join(format!("level{level}-tile{tile}.exr"));
        bin()
            .arg("denoise")
            .arg(fixture("cornell_0032spp.exr"))
            .arg("-o")
            .arg(&out)
            .args(["--search-radius", "2", "--zip-level", level, "--tile-size", tile])
            .assert()
            .success();
        out
    };
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    let mut first = None;
    for tile in ["512", "0"] {
        let (fast, small) = (write("1", tile), write("12", tile));
        // Every file's samples against the first one's (streaming, level 1).
        let first = first.get_or_insert_with(|| exrio::read_frame(&fast).unwrap());
        for path in [&fast, &small] {
            let frame = exrio::read_frame(path).unwrap();
            assert_eq!(frame.channels.len(), first.channels.len());
            for (x, y) in frame.channels.iter().zip(&first.channels) {
                assert_eq!(x.name, y.name);
                assert!(x.samples() == y.samples(), "{}: channel {}", path.display(), x.name);
            }
        }
        assert!(size(&small) < size(&fast), "tile {tile}: level 12 {} bytes, level 1 {}", size(&small), size(&fast));
    }
    let out = dir.path().join("bad.exr");
    for level in ["0", "13"] {
        let assert = bin()
            .arg("denoise")
            .arg(fixture("cornell_0032spp.exr"))
            .arg("-o")
            .arg(&out)
            .args(["--zip-level", level])
            .assert()
            .failure();
        let err = String::from_utf8(assert.get_output().stderr.clone()).unwrap();
        assert!(err.contains("zip-level"), "stderr should mention the option: {err}");
        assert!(!out.exists(), "no output may be written on error");
    }
}

/// `--denoised-only` writes the denoised channels alone, streaming or
/// whole-frame (`--tile-size 0`), with the bits a full output holds for
/// them (tiles of 16 against the whole frame: the engine's equality holds
/// for the channels it keeps), and with `--half` in half floats.
#[test]
fn denoised_only_writes_the_denoised_channels_alone() {
    let dir = tempfile::tempdir().unwrap();
    let input = fixture("cornell_0032spp.exr");
    let write = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        bin()
            .arg("denoise")
            .arg(&input)
            .arg("-o")
            .arg(&out)
            .args(["--search-radius", "3", "--layers", "auto", "--threads", "2"])
            .args(extra)
            .assert()
            .success();
        exrio::read_frame(&out).unwrap()
    };
    let all = write("all.exr", &["--tile-size", "0"]);
    let denoised = ["B", "G", "R", "direct.B", "direct.G", "direct.R", "indirect.B", "indirect.G", "indirect.R"];
    assert!(all.channels.len() > denoised.len(), "the fixture has channels to carry");
    for (name, extra) in [
        ("streamed.exr", &["--denoised-only", "--tile-size", "16"][..]),
        ("whole.exr", &["--denoised-only", "--tile-size", "0"][..]),
    ] {
        let only = write(name, extra);
        assert_eq!(only.channel_names(), denoised, "{name}");
        for c in &only.channels {
            assert_eq!(c.kind, SampleKind::F32, "{name}: {}", c.name);
            let full = all.channel(&c.name).unwrap();
            assert!(c.samples() == full.samples(), "{name}: channel {} differs from the full output's", c.name);
        }
    }
    let half = write("half.exr", &["--denoised-only", "--half"]);
    assert_eq!(half.channel_names(), denoised);
    assert!(half.channels.iter().all(|c| c.kind == SampleKind::F16));
    // `info` on such an output (no variance: not denoisable as it is) lists
    // its channels, then fails naming the file and what is missing.
    let out = dir.path().join("half.exr");
    let run = bin().arg("info").arg(&out).assert().failure();
    let (stdout, stderr) = (String::from_utf8_lossy(&run.get_output().stdout), stderr_of(&run));
    for name in denoised {
        assert!(stdout.contains(&format!("  {name:<24} half")), "{name} missing from:\n{stdout}");
    }
    assert!(stderr.contains("half.exr") && stderr.contains("no variance"), "{stderr}");
}

#[test]
fn info_prints_roles_and_plan() {
    let out = bin()
        .arg("info")
        .arg(fixture("cornell_0032spp.exr"))
        .args(["--plan", "--layers", "auto"])
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let text = String::from_utf8(out).unwrap();
    for want in [
        "colour (denoised)",
        "colour variance",
        "feature albedo",
        "feature N variance",
        "light layer direct (denoised)",
        "halo = ",
    ] {
        assert!(text.contains(want), "missing {want:?} in:\n{text}");
    }
    // Without --layers, the layers are carried and a note says how to use them.
    let out = bin().arg("info").arg(fixture("cornell_0032spp.exr")).assert().success().get_output().stdout.clone();
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("--layers auto"), "{text}");
}

/// The CLI runs itself again once with glibc's huge-pages tunable
/// (`engine::budget::exec_with_huge_pages`), unless the user opted out or
/// chose the tunable's value, or the kernel has no transparent huge pages.
#[test]
fn the_cli_asks_for_huge_pages_once_unless_told_not_to() {
    let thp = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").unwrap_or_default();
    let expected = cfg!(all(target_os = "linux", target_env = "gnu")) && !thp.is_empty() && !thp.contains("[never]");
    let run = |env: &[(&str, &str)]| {
        let mut cmd = bin();
        cmd.env_remove("GLIBC_TUNABLES").env_remove("NLDENOISE_HUGE_PAGES").env_remove("RUST_LOG");
        for (k, v) in env {
            cmd.env(k, v);
        }
        let out = cmd.args(["-vv", "info"]).arg(fixture("cornell_0032spp.exr")).assert().success().get_output().clone();
        let stderr = String::from_utf8(out.stderr).unwrap();
        stderr.lines().filter(|l| l.contains("transparent huge pages requested")).map(str::to_owned).collect::<Vec<_>>()
    };
    let once = |tunables: &str| if expected { vec![tunables.to_owned()] } else { vec![] };
    let requested = |lines: Vec<String>| -> Vec<String> {
        lines.iter().map(|l| l.split("GLIBC_TUNABLES=").nth(1).unwrap_or("").trim_end_matches(')').to_owned()).collect()
    };
    assert_eq!(requested(run(&[])), once("glibc.malloc.hugetlb=1"), "the default run");
    // A user's `1` is not taken for the re-execution's own mark.
    assert_eq!(requested(run(&[("NLDENOISE_HUGE_PAGES", "1")])), once("glibc.malloc.hugetlb=1"), "asked for");
    assert!(run(&[("NLDENOISE_HUGE_PAGES", "0")]).is_empty(), "opted out");
    assert!(run(&[("GLIBC_TUNABLES", "glibc.malloc.hugetlb=0")]).is_empty(), "the user's own value");
    // Another tunable of the user's is kept beside ours.
    assert_eq!(
        requested(run(&[("GLIBC_TUNABLES", "glibc.malloc.arena_max=1")])),
        once("glibc.malloc.arena_max=1:glibc.malloc.hugetlb=1"),
        "beside another tunable"
    );
}

#[test]
fn compare_prints_the_metrics() {
    let f = fixture("cornell_0032spp.exr");
    let out = bin().arg("compare").arg(&f).arg(&f).assert().success().get_output().stdout.clone();
    let text = String::from_utf8(out).unwrap();
    for key in ["relMSE: ", "MSE: ", "PSNR: ", "max_abs_diff: ", "bitwise_identical: yes"] {
        assert!(text.lines().any(|l| l.starts_with(key)), "missing {key:?} in:\n{text}");
    }
    let out =
        bin().arg("compare").arg(&f).arg(fixture("cornell_ref.exr")).assert().success().get_output().stdout.clone();
    assert!(String::from_utf8(out).unwrap().contains("bitwise_identical: no"));
}

#[test]
fn bad_inputs_fail_clearly_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, 1, 2, 3]).unwrap();
    for (input, extra, needle) in [
        (dir.path().join("missing.exr"), vec![], "missing.exr"),
        (garbage.clone(), vec![], "garbage.exr"),
        (fixture("cornell_0032spp.exr"), vec!["--features", "nosuch"], "nosuch"),
        (fixture("cornell_0032spp.exr"), vec!["--map", "color=Q,R,S"], "\"Q\""),
        (fixture("cornell_ref.exr"), vec!["--variance", "halves"], "half buffers"),
        (fixture("cornell_0032spp.exr"), vec!["--tau", "0"], "tau"),
    ] {
        let assert = bin().arg("denoise").arg(&input).arg("-o").arg(&out).args(&extra).assert().failure().code(1);
        let err = String::from_utf8(assert.get_output().stderr.clone()).unwrap();
        assert!(err.contains(needle), "stderr should mention {needle:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "no output may be written on error");
    }
    // Missing channels: the error lists the channels found.
    let err = bin()
        .arg("denoise")
        .arg(fixture("cornell_0032spp.exr"))
        .arg("-o")
        .arg(&out)
        .args(["--map", "layer.x=R"])
        .assert()
        .failure();
    let err = String::from_utf8(err.get_output().stderr.clone()).unwrap();
    assert!(err.contains("channels found"), "{err}");
}

/// Frames `shot.NNNN.exr` in `dir`: the fixture with its beauty (and its
/// halves) scaled by a different factor per frame, so that every frame's
/// output differs.
fn write_sequence(dir: &Path, frames: &[i64]) {
    let base = exrio::read_frame(&fixture("cornell_0032spp.exr")).unwrap();
    for &f in frames {
        let mut frame = base.clone();
        let k = 1.0 + 0.1 * (f % 10) as f32;
        for name in ["R", "G", "B", "A.R", "A.G", "A.B", "B.R", "B.G", "B.B"] {
            let scaled: Vec<f32> = frame.channel(name).unwrap().to_f32().iter().map(|v| v * k).collect();
            frame.set_channel(exrio::Channel::from_f32(name, scaled));
        }
        exrio::write_frame(&dir.join(format!("shot.{f:04}.exr")), &frame, &Default::default()).unwrap();
    }
}

/// A finished command's standard error.
fn stderr_of(run: &assert_cmd::assert::Assert) -> String {
    String::from_utf8_lossy(&run.get_output().stderr).into_owned()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

#[test]
fn a_frame_sequence_gives_each_frame_its_own_single_frame_output() {
    let dir = tempfile::tempdir().unwrap();
    let (src, out, single) = (dir.path().join("in"), dir.path().join("out"), dir.path().join("single"));
    for d in [&src, &out, &single] {
        std::fs::create_dir(d).unwrap();
    }
    write_sequence(&src, &[1001, 1002, 1003]);
    bin()
        .arg("denoise")
        .arg(src.join("shot.####.exr"))
        .arg("-o")
        .arg(out.join("den.%04d.exr"))
        .args(["--threads", "2"])
        .assert()
        .success();
    assert_eq!(files_in(&out), ["den.1001.exr", "den.1002.exr", "den.1003.exr"]);
    let mut outputs = Vec::new();
    for f in [1001, 1002, 1003] {
        let one = single.join(format!("{f}.exr"));
        bin().arg("denoise").arg(src.join(format!("shot.{f}.exr"))).arg("-o").arg(&one).assert().success();
        let (batch, alone) = (std::fs::read(out.join(format!("den.{f}.exr"))).unwrap(), std::fs::read(&one).unwrap());
        assert!(batch == alone, "frame {f}: the batch's output differs from a single-frame run's");
        outputs.push(batch);
    }
    assert!(outputs[0] != outputs[1] && outputs[1] != outputs[2], "each frame must be its own");
}

#[test]
fn frame_lists_folders_and_skip_existing() {
    let dir = tempfile::tempdir().unwrap();
    let (src, out) = (dir.path().join("in"), dir.path().join("out"));
    std::fs::create_dir(&src).unwrap();
    std::fs::create_dir(&out).unwrap();
    write_sequence(&src, &[1, 2, 3, 4, 5]);
    // An output already there is left as it is with --skip-existing.
    std::fs::write(out.join("shot.0003.exr"), b"kept").unwrap();
    bin()
        .arg("denoise")
        .arg(src.join("shot.####.exr"))
        .arg("-o")
        .arg(&out)
        .args(["--frames", "1-5x2", "--skip-existing"])
        .assert()
        .success();
    assert_eq!(files_in(&out), ["shot.0001.exr", "shot.0003.exr", "shot.0005.exr"]);
    assert_eq!(std::fs::read(out.join("shot.0003.exr")).unwrap(), b"kept");
    assert!(exrio::read_frame(&out.join("shot.0005.exr")).is_ok());
    // Several inputs (a shell glob) into a folder, under their own names.
    let many = dir.path().join("many");
    std::fs::create_dir(&many).unwrap();
    bin()
        .arg("denoise")
        .arg(src.join("shot.0002.exr"))
        .arg(src.join("shot.0004.exr"))
        .arg("-o")
        .arg(&many)
        .assert()
        .success();
    assert_eq!(files_in(&many), ["shot.0002.exr", "shot.0004.exr"]);
}

#[test]
fn a_bad_frame_stops_the_batch_or_is_listed_with_keep_going() {
    let dir = tempfile::tempdir().unwrap();
    let (src, out) = (dir.path().join("in"), dir.path().join("out"));
    std::fs::create_dir(&src).unwrap();
    std::fs::create_dir(&out).unwrap();
    write_sequence(&src, &[1, 2, 3]);
    // Frame 2 is truncated (a half-written file on the farm); frame 4 is missing.
    let bad = src.join("shot.0002.exr");
    let bytes = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 2]).unwrap();
    let stopped = bin()
        .arg("denoise")
        .arg(src.join("shot.####.exr"))
        .arg("-o")
        .arg(out.join("d.####.exr"))
        .args(["--frames", "1-4"])
        .assert()
        .failure()
        .code(1);
    let err = stderr_of(&stopped);
    assert!(err.contains("shot.0002.exr") && err.contains("stopped at frame 2 of 4"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    // Frame 1 was written, nothing after the failure, no temporary file left.
    assert_eq!(files_in(&out), ["d.0001.exr"]);
    let went_on = bin()
        .arg("denoise")
        .arg(src.join("shot.####.exr"))
        .arg("-o")
        .arg(out.join("d.####.exr"))
        .args(["--frames", "1-4", "--keep-going"])
        .assert()
        .failure()
        .code(1);
    let err = stderr_of(&went_on);
    assert!(
        err.contains("2 of 4 frames failed") && err.contains("shot.0002.exr") && err.contains("shot.0004.exr"),
        "{err}"
    );
    assert_eq!(files_in(&out), ["d.0001.exr", "d.0003.exr"]);
    assert_eq!(std::fs::read(&bad).unwrap(), &bytes[..bytes.len() / 2], "the input must not be modified");
}

#[test]
fn batch_arguments_are_checked_before_any_frame_runs() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path(), &[7]);
    let seq = dir.path().join("shot.####.exr");
    let cases: [(Vec<PathBuf>, PathBuf, Vec<&str>, &str); 4] = [
        (vec![seq.clone()], dir.path().join("out.exr"), vec![], "must be a frame pattern"),
        (vec![dir.path().join("shot.0007.exr")], dir.path().join("o.exr"), vec!["--frames", "7"], "--frames needs"),
        (vec![seq.clone()], dir.path().join("o.####.exr"), vec!["--frames", "9-1"], "ends before it starts"),
        (vec![seq.clone()], dir.path().join("nowhere/"), vec![], "does not exist"),
    ];
    for (inputs, output, extra, message) in cases {
        let run = bin().arg("denoise").args(&inputs).arg("-o").arg(&output).args(&extra).assert().failure().code(1);
        let err = stderr_of(&run);
        assert!(err.contains(message), "{inputs:?} -> {output:?}: {err}");
    }
    assert_eq!(files_in(dir.path()), ["shot.0007.exr"], "nothing may be written");
}

#[test]
fn an_error_names_its_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.exr");
    let run = bin().arg("denoise").arg(&missing).arg("-o").arg(dir.path().join("o.exr")).assert().failure().code(1);
    let err = stderr_of(&run);
    assert!(err.contains(&missing.display().to_string()), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    let run = bin()
        .arg("denoise")
        .arg(fixture("cornell_0032spp.exr"))
        .arg("-o")
        .arg(dir.path().join("o.exr"))
        .args(["--memory-limit", "1K"])
        .assert()
        .failure()
        .code(1);
    let err = stderr_of(&run);
    assert_eq!(err.matches("raise --memory-limit").count(), 1, "{err}");
}
