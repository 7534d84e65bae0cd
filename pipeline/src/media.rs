//! Pictures a person looks at: camera panels with a caption, PNG files and H.264 MP4 videos.
//!
//! Panels are composed on the GPU side of MuJoCo's renderer: the cameras are drawn side by side
//! into one offscreen buffer and the caption is written above them with MuJoCo's built-in font,
//! so no font or image crate is needed. Every function here returns or takes **upright** frames.
//! MP4s are encoded by Debian's `ffmpeg` (libx264, yuv420p: what browsers play) over a pipe.

use anyhow::{Context, Result, bail};
use libero_sim::env::LiberoEnv;
use libero_sim::render::{DEFAULT_SIZE, Frame, Look, Orientation, Quality, Rect, RenderOptions, SceneRenderer};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

/// Characters per caption line per 256 px of panel width (MuJoCo's normal font at scale 150).
const CHARS_PER_256PX: usize = 25;
/// Pixel height of one caption line (MuJoCo's normal font at scale 150, with spacing).
const LINE_HEIGHT: u32 = 33;
const CAPTION_BACKGROUND: [f32; 3] = [0.08, 0.08, 0.1];

/// The cameras a person looks at: what the policy sees from outside and from the wrist.
pub const CAMERAS: [&str; 2] = ["agentview", "robot0_eye_in_hand"];

/// How panels for a person are rendered (shared by `smoke` and `video`).
#[derive(clap::Args)]
pub struct PanelArgs {
    /// Camera size in pixels.
    #[arg(long, default_value_t = DEFAULT_SIZE)]
    size: u32,
    /// Texture look: mujoco-3.2.3 (the published stack, default) or mujoco-3.3.7.
    #[arg(long, default_value = "mujoco-3.2.3")]
    pub look: Look,
    /// Fast preview quality (no shadows, reflections or multisampling); not what policies see.
    #[arg(long)]
    preview: bool,
}

impl Default for PanelArgs {
    /// What the command line gives when no option is named.
    fn default() -> Self {
        PanelArgs { size: DEFAULT_SIZE, look: Look::default(), preview: false }
    }
}

impl PanelArgs {
    /// [`CAMERAS`] side by side under a 4-line caption.
    pub fn layout(&self) -> PanelLayout {
        PanelLayout {
            cameras: CAMERAS.map(String::from).to_vec(),
            camera_width: self.size,
            camera_height: self.size,
            caption_lines: 4,
        }
    }

    /// ALOHA-sim's panel: the `top` camera at the 640 × 480 a policy sees, under a 4-line caption.
    pub fn aloha_layout(&self) -> PanelLayout {
        use libero_sim::aloha::env::{TOP_CAMERA, TOP_HEIGHT, TOP_WIDTH};
        PanelLayout {
            cameras: vec![TOP_CAMERA.to_string()],
            camera_width: TOP_WIDTH,
            camera_height: TOP_HEIGHT,
            caption_lines: 4,
        }
    }

    /// Render options for ALOHA-sim's scene: its own look (MuJoCo 3.3.7's, what its policies
    /// see), the quality asked for, a buffer that holds `layout`.
    pub fn aloha_options(&self, layout: &PanelLayout) -> RenderOptions {
        RenderOptions { look: Look::Mujoco337, ..self.options(layout) }
    }

    /// Render options whose offscreen buffer holds `layout`.
    pub fn options(&self, layout: &PanelLayout) -> RenderOptions {
        RenderOptions {
            look: self.look,
            quality: if self.preview { Quality::Preview } else { Quality::Reference },
            max_width: layout.width(),
            max_height: layout.height(),
        }
    }
}

/// Cameras side by side, each `camera_width`×`camera_height`, under a caption of `caption_lines` lines.
#[derive(Debug, Clone)]
pub struct PanelLayout {
    pub cameras: Vec<String>,
    pub camera_width: u32,
    pub camera_height: u32,
    pub caption_lines: u32,
}

impl PanelLayout {
    pub fn caption_height(&self) -> u32 {
        // Even, so that yuv420p video (2×2 chroma blocks) needs no padding.
        (self.caption_lines * LINE_HEIGHT + 8).next_multiple_of(2)
    }
    pub fn width(&self) -> u32 {
        self.camera_width * self.cameras.len() as u32
    }
    pub fn height(&self) -> u32 {
        self.camera_height + self.caption_height()
    }
    /// Where camera `i` is drawn and where the caption goes, in the buffer.
    fn camera_rect(&self, i: usize) -> Rect {
        Rect::new(i as u32 * self.camera_width, 0, self.camera_width, self.camera_height)
    }
    fn caption_rect(&self) -> Rect {
        Rect::new(0, self.camera_height, self.width(), self.caption_height())
    }
    /// Wrap `text` to the panel width; at most `caption_lines` lines (the last one cut with "...": the font is ASCII).
    pub fn wrap(&self, text: &str) -> String {
        wrap(text, CHARS_PER_256PX * self.width() as usize / 256, self.caption_lines as usize)
    }
}

/// Render the env's current state as a panel: caption (wrapped) on top, cameras below.
pub fn render_panel(
    env: &mut LiberoEnv,
    renderer: &mut SceneRenderer,
    layout: &PanelLayout,
    caption: &str,
) -> Result<Frame> {
    compose_panel(renderer, layout, caption, |r, id, rect| env.draw_camera(r, id, rect))
}

/// [`render_panel`] for an ALOHA-sim env (its `top` camera, [`PanelArgs::aloha_layout`]).
pub fn render_aloha_panel(
    env: &mut libero_sim::aloha::AlohaEnv,
    renderer: &mut SceneRenderer,
    layout: &PanelLayout,
    caption: &str,
) -> Result<Frame> {
    compose_panel(renderer, layout, caption, |r, id, rect| env.draw_camera(r, id, rect))
}

/// `layout`'s cameras drawn by `draw` (an env's own camera drawing), the caption over them, the
/// whole panel read back upright.
fn compose_panel(
    renderer: &mut SceneRenderer,
    layout: &PanelLayout,
    caption: &str,
    mut draw: impl FnMut(&mut SceneRenderer, usize, Rect) -> Result<(), libero_sim::SimError>,
) -> Result<Frame> {
    let ids = layout.cameras.iter().map(|c| renderer.camera_id(c)).collect::<Result<Vec<_>, _>>()?;
    for (i, id) in ids.into_iter().enumerate() {
        draw(renderer, id, layout.camera_rect(i))?;
    }
    renderer.draw_text(layout.caption_rect(), &layout.wrap(caption), CAPTION_BACKGROUND)?;
    Ok(renderer.read(Rect::new(0, 0, layout.width(), layout.height()))?.upright())
}

/// A full-panel text card (e.g. the outcome at the end of a video), upright.
pub fn render_card(
    renderer: &mut SceneRenderer,
    width: u32,
    height: u32,
    text: &str,
    background: [f32; 3],
) -> Result<Frame> {
    let rect = Rect::new(0, 0, width, height);
    renderer.draw_text(rect, text, background)?;
    Ok(renderer.read(rect)?.upright())
}

/// Greedy word wrap to `width` characters, at most `max_lines` lines.
pub fn wrap(text: &str, width: usize, max_lines: usize) -> String {
    let mut lines: Vec<String> = Vec::new();
    for paragraph in text.split('\n') {
        let mut line = String::new();
        for word in paragraph.split_whitespace() {
            if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
                lines.push(std::mem::take(&mut line));
            }
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(word);
        }
        lines.push(line);
    }
    if lines.len() > max_lines {
        lines.truncate(max_lines);
        if let Some(last) = lines.last_mut() {
            let keep: String = last.chars().take(width.saturating_sub(3)).collect();
            *last = format!("{keep}...");
        }
    }
    lines.join("\n")
}

/// Write an upright frame as an RGB PNG.
pub fn write_png(path: &Path, frame: &Frame) -> Result<()> {
    assert_eq!(frame.orientation, Orientation::Upright, "PNGs are written upright");
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), frame.width, frame.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(&frame.rgb)?;
    writer.finish()?;
    Ok(())
}

/// An H.264 MP4 being written by an `ffmpeg` child process from raw RGB frames, at a constant
/// frame rate from 0. Dropped unfinished (a failed export or render), it kills its ffmpeg.
pub struct Mp4Writer {
    /// None once finished.
    child: Option<Child>,
    stdin: Option<ChildStdin>,
    path: PathBuf,
    size: (u32, u32),
    frames: u64,
}

/// What browsers play: libx264 in yuv420p.
const BROWSER_H264: &[&str] = &["-c:v", "libx264", "-preset", "medium", "-crf", "20", "-pix_fmt", "yuv420p"];

impl Mp4Writer {
    /// Start `ffmpeg` writing `path` (`width`, `height` even) at `fps` frames per second.
    pub fn create(path: &Path, width: u32, height: u32, fps: u32) -> Result<Self> {
        if !width.is_multiple_of(2) || !height.is_multiple_of(2) {
            bail!("video size {width}x{height} must be even for yuv420p");
        }
        Self::create_encoded(path, width, height, fps, BROWSER_H264)
    }

    /// As [`Mp4Writer::create`], encoded by `encoder` (ffmpeg output options, e.g. `-c:v ...`).
    pub fn create_encoded(path: &Path, width: u32, height: u32, fps: u32, encoder: &[&str]) -> Result<Self> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let mut child = Command::new("ffmpeg")
            .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{width}x{height}"), "-r", &fps.to_string(), "-i", "-"])
            .args(encoder)
            .args(["-movflags", "+faststart"])
            .arg(path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                anyhow::anyhow!(
                    "cannot start ffmpeg ({e}); install it: `apt-get install ffmpeg` (./setup.sh does it as root)"
                )
            })?;
        let stdin = child.stdin.take();
        Ok(Mp4Writer { child: Some(child), stdin, path: path.to_path_buf(), size: (width, height), frames: 0 })
    }

    pub fn push(&mut self, frame: &Frame) -> Result<()> {
        assert_eq!(frame.orientation, Orientation::Upright, "videos are written upright");
        if (frame.width, frame.height) != self.size {
            bail!("frame is {}x{}, the video {}x{}", frame.width, frame.height, self.size.0, self.size.1);
        }
        self.push_rgb(&frame.rgb)
    }

    /// One frame of RGB rows, top-down, of the video's size.
    pub fn push_rgb(&mut self, rgb: &[u8]) -> Result<()> {
        if rgb.len() != (self.size.0 * self.size.1 * 3) as usize {
            bail!("a frame of {} bytes is not {}x{} RGB", rgb.len(), self.size.0, self.size.1);
        }
        let stdin = self.stdin.as_mut().expect("open until finish");
        stdin.write_all(rgb).with_context(|| format!("ffmpeg stopped while writing {}", self.path.display()))?;
        self.frames += 1;
        Ok(())
    }

    /// Close the pipe and wait for ffmpeg; returns the number of frames written.
    pub fn finish(mut self) -> Result<u64> {
        drop(self.stdin.take());
        let child = self.child.take().expect("running until finished");
        let out = child.wait_with_output().context("waiting for ffmpeg")?;
        if !out.status.success() {
            bail!("ffmpeg failed writing {}: {}", self.path.display(), String::from_utf8_lossy(&out.stderr).trim());
        }
        Ok(self.frames)
    }
}

impl Drop for Mp4Writer {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_breaks_at_words_and_cuts_overflow() {
        assert_eq!(wrap("put the bowl on the plate", 12, 3), "put the bowl\non the plate");
        assert_eq!(wrap("a b c d e f g h", 5, 2), "a b c\nd ...");
        assert_eq!(wrap("line one\nline two", 40, 3), "line one\nline two");
    }
}
