//! Prismatic's vision backbone: timm ViT featurizers run to the output of their second-to-last block
//! (openvla patches `forward` to `get_intermediate_layers(n={depth - 2})`: no final norm, prefix
//! tokens dropped), the fused pair (DINOv2 + SigLIP) concatenated along channels, and the
//! projector into the language model's width.
//!
//! A timm `VisionTransformer` block: `x + ls1(attn(norm1(x)))`, then `x + ls2(mlp(norm2(x)))`, with
//! LayerNorm eps 1e-6, a fused `qkv` linear with bias, and LayerScale (`scale_factor`, prismatic's
//! rename of timm's `gamma`) where the checkpoint has it (DINOv2). The token sequence is
//! `[class token?, register tokens?, patches]`; the position embedding covers either the patches
//! only (timm's `no_embed_class`, DINOv2) or the whole sequence.

use super::weights::Weights;
use super::{OpenVlaError, bad};
use crate::models::quant::Linear;
use tch::Tensor;

const LN_EPS: f64 = 1e-6;

/// A linear layer with its bias.
type Affine = (Linear, Tensor);

struct Block {
    norm1: (Tensor, Tensor),
    qkv: Affine,
    proj: Affine,
    ls1: Option<Tensor>,
    norm2: (Tensor, Tensor),
    fc1: Affine,
    fc2: Affine,
    ls2: Option<Tensor>,
}

/// One timm ViT featurizer.
pub struct Vit {
    patch: (Tensor, Tensor),
    patch_size: i64,
    embed_dim: i64,
    num_heads: i64,
    prefix: Option<Tensor>,
    num_prefix: i64,
    pos_embed: Tensor,
    /// the position embedding covers only the patches (timm's `no_embed_class`)
    pos_patches_only: bool,
    norm_pre: Option<(Tensor, Tensor)>,
    blocks: Vec<Block>,
    quick_gelu: bool,
}

fn ln(x: &Tensor, (w, b): &(Tensor, Tensor)) -> Tensor {
    x.layer_norm([w.size()[0]], Some(w), Some(b), LN_EPS, true)
}

fn linear(x: &Tensor, (w, b): &Affine) -> Tensor {
    w.forward(x, Some(b))
}

impl Vit {
    /// The featurizer under `prefix` (`vision_backbone.featurizer.` / `.fused_featurizer.`); only the
    /// blocks up to the second-to-last are kept.
    pub fn load(
        w: &mut Weights,
        prefix: &str,
        num_heads: i64,
        quick_gelu: bool,
        image_size: i64,
    ) -> Result<Self, OpenVlaError> {
        let p = |s: &str| format!("{prefix}{s}");
        let patch_w = w.take(&p("patch_embed.proj.weight"))?;
        let patch_b = w.take(&p("patch_embed.proj.bias"))?;
        let (embed_dim, patch_size) = (patch_w.size()[0], patch_w.size()[2]);
        if embed_dim % num_heads != 0 {
            return Err(bad(format!("{prefix}: width {embed_dim} is not a multiple of {num_heads} heads")));
        }
        let cls = w.take_opt(&p("cls_token"));
        let reg = w.take_opt(&p("reg_token"));
        let prefix_tokens: Vec<Tensor> = cls.into_iter().chain(reg).collect();
        let num_prefix: i64 = prefix_tokens.iter().map(|t| t.size()[1]).sum();
        let prefix_t = if prefix_tokens.is_empty() { None } else { Some(Tensor::cat(&prefix_tokens, 1)) };
        let pos_embed = w.take(&p("pos_embed"))?;
        let grid = image_size / patch_size;
        let n_patches = grid * grid;
        let pos_len = pos_embed.size()[1];
        let pos_patches_only = if pos_len == n_patches {
            true
        } else if pos_len == n_patches + num_prefix {
            false
        } else {
            return Err(bad(format!(
                "{prefix}pos_embed has {pos_len} positions; {n_patches} patches of a {image_size}px image and \
                 {num_prefix} prefix tokens need {n_patches} or {}",
                n_patches + num_prefix
            )));
        };
        let norm_pre = match w.take_opt(&p("norm_pre.weight")) {
            Some(nw) => Some((nw, w.take(&p("norm_pre.bias"))?)),
            None => None,
        };
        let depth = w.count_indexed(&p("blocks."));
        if depth < 2 {
            return Err(bad(format!("{prefix}: {depth} blocks; the featurizer reads the second-to-last")));
        }
        let mut blocks = Vec::new();
        for i in 0..depth - 1 {
            let b = |s: &str| format!("{prefix}blocks.{i}.{s}");
            let norm = |w: &mut Weights, s: &str| -> Result<(Tensor, Tensor), OpenVlaError> {
                Ok((w.take(&b(&format!("{s}.weight")))?, w.take(&b(&format!("{s}.bias")))?))
            };
            let affine = |w: &mut Weights, s: &str| -> Result<Affine, OpenVlaError> {
                Ok((w.take_linear(&b(&format!("{s}.weight")))?, w.take(&b(&format!("{s}.bias")))?))
            };
            blocks.push(Block {
                norm1: norm(w, "norm1")?,
                qkv: affine(w, "attn.qkv")?,
                proj: affine(w, "attn.proj")?,
                norm2: norm(w, "norm2")?,
                fc1: affine(w, "mlp.fc1")?,
                fc2: affine(w, "mlp.fc2")?,
                ls1: w.take_opt(&b("ls1.scale_factor")),
                ls2: w.take_opt(&b("ls2.scale_factor")),
            });
        }
        Ok(Vit {
            patch: (patch_w, patch_b),
            patch_size,
            embed_dim,
            num_heads,
            prefix: prefix_t,
            num_prefix,
            pos_embed,
            pos_patches_only,
            norm_pre,
            blocks,
            quick_gelu,
        })
    }

    pub fn embed_dim(&self) -> i64 {
        self.embed_dim
    }

    /// `[B, 3, H, W]` normalised pixels → `[B, patches, embed_dim]`.
    // tch's `x += y` is in place (`add_`); these new tensors are built without touching their inputs
    #[allow(clippy::assign_op_pattern)]
    pub fn forward(&self, img: &Tensor) -> Tensor {
        let b = img.size()[0];
        let ps = self.patch_size;
        let x =
            img.conv2d(&self.patch.0, Some(&self.patch.1), [ps, ps], [0, 0], [1, 1], 1).flatten(2, 3).transpose(1, 2);
        let prefix = self.prefix.as_ref().map(|t| t.expand([b, -1, -1], false));
        let mut x = match (&prefix, self.pos_patches_only) {
            (Some(pre), true) => Tensor::cat(&[pre, &(x + &self.pos_embed)], 1),
            (Some(pre), false) => Tensor::cat(&[pre, &x], 1) + &self.pos_embed,
            (None, _) => x + &self.pos_embed,
        };
        if let Some(np) = &self.norm_pre {
            x = ln(&x, np);
        }
        for blk in &self.blocks {
            let mut a = self.attention(&ln(&x, &blk.norm1), blk);
            if let Some(g) = &blk.ls1 {
                a = a * g;
            }
            x = x + a;
            let h = linear(&ln(&x, &blk.norm2), &blk.fc1);
            let h = if self.quick_gelu { &h * (&h * 1.702).sigmoid() } else { h.gelu("none") };
            let mut m = linear(&h, &blk.fc2);
            if let Some(g) = &blk.ls2 {
                m = m * g;
            }
            x = x + m;
        }
        x.narrow(1, self.num_prefix, x.size()[1] - self.num_prefix)
    }

    fn attention(&self, x: &Tensor, blk: &Block) -> Tensor {
        let (b, n, c) = (x.size()[0], x.size()[1], x.size()[2]);
        let hd = c / self.num_heads;
        let qkv = linear(x, &blk.qkv).reshape([b, n, 3, self.num_heads, hd]).permute([2, 0, 3, 1, 4]);
        let (q, k, v) = (qkv.get(0), qkv.get(1), qkv.get(2));
        let o = Tensor::scaled_dot_product_attention(&q, &k, &v, None::<Tensor>, 0.0, false, None, false);
        linear(&o.transpose(1, 2).reshape([b, n, c]), &blk.proj)
    }
}

/// The vision backbone(s) and the projector: `pixel_values` `[B, 3·k, H, W]` → `[B, patches, llm]`.
pub struct VisionTower {
    featurizers: Vec<Vit>,
    /// `fc1, fc2[, fc3]` with GELU between (the fused backbone's `fused-gelu-mlp` has three).
    projector: Vec<Affine>,
}

impl VisionTower {
    pub fn new(featurizers: Vec<Vit>, w: &mut Weights) -> Result<Self, OpenVlaError> {
        let mut projector = Vec::new();
        for i in 1..=3 {
            let weight = format!("projector.fc{i}.weight");
            if !w.has(&weight) {
                break;
            }
            projector.push((w.take_linear(&weight)?, w.take(&format!("projector.fc{i}.bias"))?));
        }
        let width: i64 = featurizers.iter().map(Vit::embed_dim).sum();
        if projector.len() < 2 || projector[0].0.size()[1] != width {
            return Err(bad(format!("projector: expected fc1 (from width {width}), fc2[, fc3]")));
        }
        Ok(VisionTower { featurizers, projector })
    }

    /// The featurizers' patch features, concatenated along channels.
    pub fn patch_features(&self, pixel_values: &Tensor) -> Tensor {
        let parts: Vec<Tensor> = self
            .featurizers
            .iter()
            .enumerate()
            .map(|(i, f)| f.forward(&pixel_values.narrow(1, 3 * i as i64, 3)))
            .collect();
        Tensor::cat(&parts, 2)
    }

    pub fn project(&self, patches: &Tensor) -> Tensor {
        let mut x = patches.shallow_clone();
        for (i, layer) in self.projector.iter().enumerate() {
            if i > 0 {
                x = x.gelu("none");
            }
            x = linear(&x, layer);
        }
        x
    }
}
