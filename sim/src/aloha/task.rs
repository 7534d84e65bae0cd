//! The two ALOHA-sim tasks and how an episode's objects are placed.
//!
//! gym-aloha 0.1.5 registers `gym_aloha/AlohaTransferCube-v0` and `gym_aloha/AlohaInsertion-v0`,
//! joint-space tasks on `bimanual_viperx_{transfer_cube,insertion}.xml`. The only randomness of an
//! episode is where its objects start: `gym_aloha/utils.py` draws the cube (or the peg, then the
//! socket) from `RandomState(seed).uniform`, with the identity orientation; the draw becomes
//! `qpos[16..]` at reset (aloha-sim.md §3).

use super::mt19937::RandomState;

/// An ALOHA-sim task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum AlohaTask {
    /// Pick the red cube with the right arm and hand it to the left.
    TransferCube,
    /// Pick the peg (right) and the socket (left) and insert the peg into the socket.
    Insertion,
}

/// `sample_box_pose`'s ranges: x ∈ [0, 0.2], y ∈ [0.4, 0.6], z = 0.05.
const BOX_LOW: [f64; 3] = [0.0, 0.4, 0.05];
const BOX_HIGH: [f64; 3] = [0.2, 0.6, 0.05];
/// `sample_insertion_pose`'s peg ranges, drawn first.
const PEG_LOW: [f64; 3] = [0.1, 0.4, 0.05];
const PEG_HIGH: [f64; 3] = [0.2, 0.6, 0.05];
/// `sample_insertion_pose`'s socket ranges, drawn second from the same generator.
const SOCKET_LOW: [f64; 3] = [-0.2, 0.4, 0.05];
const SOCKET_HIGH: [f64; 3] = [-0.1, 0.6, 0.05];
/// The objects' orientation, (w, x, y, z).
const IDENTITY: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

impl AlohaTask {
    pub const ALL: [AlohaTask; 2] = [AlohaTask::TransferCube, AlohaTask::Insertion];

    /// The task of a spec row's `task_id` (the order of [`AlohaTask::ALL`]).
    pub fn from_id(task_id: i64) -> Option<AlohaTask> {
        usize::try_from(task_id).ok().and_then(|i| AlohaTask::ALL.get(i).copied())
    }

    /// The spec rows' `task_id` of this task.
    pub fn id(self) -> i32 {
        self as i32
    }

    /// The instruction a language-conditioned policy is given: openpi's ALOHA-sim example prompts
    /// "Transfer cube" (its `pi0_aloha_sim` was trained on it); the insertion's is the task's.
    pub fn instruction(self) -> &'static str {
        match self {
            AlohaTask::TransferCube => "Transfer cube",
            AlohaTask::Insertion => "Insert the peg into the socket",
        }
    }

    /// The free objects, in `qpos[16..]` order (their free joints' names without `_joint`).
    pub fn object_names(self) -> &'static [&'static str] {
        match self {
            AlohaTask::TransferCube => &["red_box"],
            AlohaTask::Insertion => &["red_peg", "blue_socket"],
        }
    }

    /// gym-aloha's task name (`AlohaEnv(task=...)`), also ours.
    pub fn name(self) -> &'static str {
        match self {
            AlohaTask::TransferCube => "transfer_cube",
            AlohaTask::Insertion => "insertion",
        }
    }

    /// The gymnasium id gym-aloha registers.
    pub fn gym_id(self) -> &'static str {
        match self {
            AlohaTask::TransferCube => "gym_aloha/AlohaTransferCube-v0",
            AlohaTask::Insertion => "gym_aloha/AlohaInsertion-v0",
        }
    }

    /// The joint-space scene file of the wheel's `assets/`.
    pub fn scene_file(self) -> &'static str {
        match self {
            AlohaTask::TransferCube => "bimanual_viperx_transfer_cube.xml",
            AlohaTask::Insertion => "bimanual_viperx_insertion.xml",
        }
    }

    /// The end-effector twin of [`scene_file`](Self::scene_file) (ACT's `*_ee` envs: the same
    /// scene with a mocap body welded to each gripper and only the 4 finger actuators), which the
    /// scripted positive control drives ([`super::scripted`]); gym-aloha ships it but cannot run it.
    pub fn end_effector_scene_file(self) -> &'static str {
        match self {
            AlohaTask::TransferCube => "bimanual_viperx_end_effector_transfer_cube.xml",
            AlohaTask::Insertion => "bimanual_viperx_end_effector_insertion.xml",
        }
    }

    /// Free-jointed objects after the 16 arm joints: the cube; or the peg, then the socket.
    pub fn objects(self) -> usize {
        match self {
            AlohaTask::TransferCube => 1,
            AlohaTask::Insertion => 2,
        }
    }

    /// `qpos[16..]` of the episode seeded `seed`: position then (w, x, y, z) of each object, as
    /// `sample_box_pose(seed)` / `np.concatenate(sample_insertion_pose(seed))` return it.
    pub fn initial_pose(self, seed: u32) -> Vec<f64> {
        let mut rng = RandomState::new(seed);
        let mut out = Vec::with_capacity(7 * self.objects());
        let ranges: &[([f64; 3], [f64; 3])] = match self {
            AlohaTask::TransferCube => &[(BOX_LOW, BOX_HIGH)],
            AlohaTask::Insertion => &[(PEG_LOW, PEG_HIGH), (SOCKET_LOW, SOCKET_HIGH)],
        };
        for &(low, high) in ranges {
            out.extend(rng.uniform(low, high));
            out.extend(IDENTITY);
        }
        out
    }
}

impl std::fmt::Display for AlohaTask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for AlohaTask {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        AlohaTask::ALL
            .into_iter()
            .find(|t| t.name() == s || t.gym_id() == s)
            .ok_or_else(|| format!("unknown ALOHA task {s:?}; the tasks are transfer_cube and insertion"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_1000_gives_the_poses_numpy_draws() {
        // aloha-sim.md §3, from gym_aloha.utils on numpy 1.26.4.
        let cube = AlohaTask::TransferCube.initial_pose(1000);
        assert_eq!(cube, [0.1307179170929219, 0.4230013886248812, 0.05, 1.0, 0.0, 0.0, 0.0]);
        let pair = AlohaTask::Insertion.initial_pose(1000);
        assert_eq!(&pair[..3], &[0.16535895854646096, 0.4230013886248812, 0.05]);
        assert_eq!(&pair[7..10], &[-0.1517808598572002, 0.574494907036407, 0.05]);
        assert_eq!((&pair[3..7], &pair[10..]), (&IDENTITY[..], &IDENTITY[..]));
    }

    #[test]
    fn task_ids_are_the_order_of_all() {
        for t in AlohaTask::ALL {
            assert_eq!(AlohaTask::from_id(t.id() as i64), Some(t));
            assert_eq!(t.object_names().len(), t.objects());
        }
        assert_eq!(AlohaTask::from_id(2), None);
        assert_eq!(AlohaTask::from_id(-1), None);
    }

    #[test]
    fn names_parse_back() {
        for t in AlohaTask::ALL {
            assert_eq!(t.name().parse::<AlohaTask>().unwrap(), t);
            assert_eq!(t.gym_id().parse::<AlohaTask>().unwrap(), t);
        }
        assert!("pick_place".parse::<AlohaTask>().unwrap_err().contains("transfer_cube"));
    }
}
