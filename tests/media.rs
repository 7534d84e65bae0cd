//! Media through the binary: smoke pictures (upright, the published look) and replay videos
//! (H.264 in an MP4 a browser plays, checked with ffprobe), and the errors a user meets.

use libero_e2e::{pipeline_bin, read_png, repo_root};
use libero_sim::render::{Frame, Orientation};
use std::process::{Command, Output};

fn pipeline(args: &[&str]) -> Output {
    Command::new(pipeline_bin()).args(args).current_dir(repo_root()).env("RUST_BACKTRACE", "0").output().unwrap()
}

fn ok(out: &Output) -> String {
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "pipeline failed:\n{text}");
    text
}

/// The `size`×`size` tile at the panel's bottom-left (the agentview camera), upright.
fn bottom_left_tile(panel: &Frame, size: u32) -> Frame {
    let (w, h, s) = (panel.width as usize, panel.height as usize, size as usize);
    let mut rgb = Vec::with_capacity(s * s * 3);
    for row in h - s..h {
        rgb.extend_from_slice(&panel.rgb[row * w * 3..(row * w + s) * 3]);
    }
    Frame { width: size, height: size, rgb, orientation: Orientation::Upright }
}

#[test]
fn smoke_pictures_are_upright_captioned_and_in_the_published_look() {
    let dir = tempdir("smoke");
    let out =
        pipeline(&["smoke", "--out", dir.to_str().unwrap(), "--suites", "libero_spatial,libero_object", "--seed", "0"]);
    ok(&out);
    for suite in ["libero_spatial", "libero_object"] {
        let panel = read_png(&dir.join(format!("{suite}.png")), Orientation::Upright);
        assert_eq!(panel.width, 512, "two 256-px cameras side by side");
        assert!(panel.height > 256, "a caption strip above the cameras");
        // The agentview tile is the reference env's frame on MuJoCo 3.2.3 (same state: task 0,
        // init 0, seed 0), turned upright for a person.
        let ours = bottom_left_tile(&panel, 256);
        let reference = read_png(
            &repo_root().join(format!("data/frames/mujoco-3.2.3/{suite}__00__init0__s000__agentview.png")),
            Orientation::Reference,
        );
        let upright = ours.psnr(&reference.upright());
        let as_stored = ours.psnr(&Frame { orientation: Orientation::Upright, ..reference.clone() });
        println!("{suite}: PSNR vs the reference turned upright {upright:.1} dB, vs it unturned {as_stored:.1} dB");
        assert!(upright >= 40.0, "{suite}: smoke picture differs from the reference frame: {upright:.1} dB");
        assert!(
            as_stored < 25.0,
            "{suite}: the picture is not turned upright ({as_stored:.1} dB against the raw frame)"
        );
        // The caption strip holds text: bright pixels on the dark background.
        let caption_rows = (panel.height - 256) as usize;
        let bright = panel.rgb[..caption_rows * 512 * 3].iter().filter(|&&v| v > 200).count();
        assert!(bright > 500, "{suite}: no caption text ({bright} bright values)");
    }
}

#[test]
fn a_replay_video_is_h264_yuv420p_with_one_frame_per_two_steps_and_an_outcome_card() {
    let dir = tempdir("video");
    let d = dir.to_str().unwrap();
    let specs = format!("{d}/specs.parquet");
    ok(&pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", &specs]));
    ok(&pipeline(&["run", &specs, "--out", &format!("{d}/run"), "--policy", "random", "--max-steps", "20"]));
    let text = ok(&pipeline(&[
        "video",
        "--run",
        &format!("{d}/run"),
        "--episode",
        "libero_spatial/0/0/7",
        "--out",
        &format!("{d}/videos"),
        "--preview",
    ]));
    assert!(text.contains("of all 30 steps"), "{text}");
    let mp4 = dir.join("videos/libero_spatial_task0_init0.mp4");
    let probe = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_frames", "-show_entries"])
        .args(["stream=codec_name,pix_fmt,width,height,nb_read_frames,r_frame_rate", "-of", "default=nw=1"])
        .arg(&mp4)
        .output()
        .unwrap();
    let probe = String::from_utf8_lossy(&probe.stdout);
    println!("{probe}");
    // 1 frame of the init state + 30 env steps (10 wait + 20 policy) / 2 + 2 s of outcome card.
    for expected in ["codec_name=h264", "pix_fmt=yuv420p", "width=512", "r_frame_rate=10/1", "nb_read_frames=36"] {
        assert!(probe.contains(expected), "ffprobe lacks {expected}:\n{probe}");
    }

    // A key the run does not hold is named, with the query that lists the ones it does.
    let out = pipeline(&["video", "--run", &format!("{d}/run"), "--episode", "libero_spatial/0/9/7"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("no episode") && err.contains("SELECT episode_key"), "{err}");
}

#[test]
fn without_egl_the_error_names_the_packages_to_install() {
    let dir = tempdir("no-egl");
    let out = Command::new(pipeline_bin())
        .args(["smoke", "--out", dir.to_str().unwrap(), "--suites", "libero_spatial"])
        .current_dir(repo_root())
        .env("__EGL_VENDOR_LIBRARY_DIRS", "/nonexistent")
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "rendering should fail without an EGL vendor library");
    assert!(err.contains("no headless OpenGL") && err.contains("apt-get install libegl1"), "{err}");
}

fn tempdir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("libero-media-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
