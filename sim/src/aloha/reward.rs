//! The reward, 0–4, from the contacts of the state after a step (`get_reward` of gym-aloha's
//! `TransferCubeTask` and `InsertionTask`).
//!
//! gym-aloha builds the set of *ordered* `(name(geom1), name(geom2))` pairs over the active
//! contacts and tests membership, e.g. `("red_box", "table")`. MuJoCo orders a pair by geom type
//! (box before mesh), so the order is part of the rule: a pair listed the other way round never
//! matches. [`ContactReward`] resolves the names to geom ids once and tests the same ordered
//! pairs on ids. Later conditions overwrite earlier ones, exactly as in the Python.
//! Success is reward 4 ([`MAX_REWARD`]); the env then terminates (`terminated = reward == 4`).

use super::task::AlohaTask;
use crate::SimError;
use crate::scene::object_id;
use mujoco_rs::mujoco_c::mjContact;
use mujoco_rs::prelude::*;

/// The reward of a solved task.
pub const MAX_REWARD: u8 = 4;

const TABLE: &str = "table";
const LEFT_FINGER: &str = "vx300s_left/10_left_gripper_finger";
const RIGHT_FINGER: &str = "vx300s_right/10_right_gripper_finger";
const BOX: &str = "red_box";
const PEG: &str = "red_peg";
const SOCKET_WALLS: [&str; 4] = ["socket-1", "socket-2", "socket-3", "socket-4"];
const PIN: &str = "pin";

type Geom = i32;

/// A task's reward rule over geom ids resolved from the compiled model.
#[derive(Debug, Clone)]
pub enum ContactReward {
    TransferCube { cube: Geom, left: Geom, right: Geom, table: Geom },
    Insertion { peg: Geom, sockets: [Geom; 4], pin: Geom, left: Geom, right: Geom, table: Geom },
}

impl ContactReward {
    /// Resolve the task's geom names in `model`; a missing name is an error naming it.
    pub fn new(task: AlohaTask, model: &MjModel) -> Result<Self, SimError> {
        let id = |name: &str| object_id(model, MjtObj::mjOBJ_GEOM, name, "geom").map(|g| g as Geom);
        Ok(match task {
            AlohaTask::TransferCube => ContactReward::TransferCube {
                cube: id(BOX)?,
                left: id(LEFT_FINGER)?,
                right: id(RIGHT_FINGER)?,
                table: id(TABLE)?,
            },
            AlohaTask::Insertion => ContactReward::Insertion {
                peg: id(PEG)?,
                sockets: [id(SOCKET_WALLS[0])?, id(SOCKET_WALLS[1])?, id(SOCKET_WALLS[2])?, id(SOCKET_WALLS[3])?],
                pin: id(PIN)?,
                left: id(LEFT_FINGER)?,
                right: id(RIGHT_FINGER)?,
                table: id(TABLE)?,
            },
        })
    }

    /// The reward of a state whose contacts are `contacts` (those of its last collision pass).
    /// The pairs are read from `geom1`/`geom2`, the fields gym-aloha reads.
    pub fn evaluate(&self, contacts: &[mjContact]) -> u8 {
        let has = |a: Geom, b: Geom| contacts.iter().any(|c| c.geom1 == a && c.geom2 == b);
        match *self {
            ContactReward::TransferCube { cube, left, right, table } => {
                let touch_left = has(cube, left);
                let touch_right = has(cube, right);
                let touch_table = has(cube, table);
                let mut reward = 0;
                if touch_right {
                    reward = 1;
                }
                if touch_right && !touch_table {
                    reward = 2; // lifted
                }
                if touch_left {
                    reward = 3; // attempted transfer
                }
                if touch_left && !touch_table {
                    reward = 4; // transferred
                }
                reward
            }
            ContactReward::Insertion { peg, sockets, pin, left, right, table } => {
                let touch_right = has(peg, right);
                let touch_left = sockets.iter().any(|&s| has(s, left));
                let peg_table = has(peg, table);
                let socket_table = sockets.iter().any(|&s| has(s, table));
                let peg_socket = sockets.iter().any(|&s| has(peg, s));
                let pin_touched = has(peg, pin);
                let mut reward = 0;
                if touch_left && touch_right {
                    reward = 1; // both touched
                }
                if touch_left && touch_right && !peg_table && !socket_table {
                    reward = 2; // both grasped
                }
                if peg_socket && !peg_table && !socket_table {
                    reward = 3; // peg and socket touching
                }
                if pin_touched {
                    reward = 4; // inserted
                }
                reward
            }
        }
    }
}
