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
