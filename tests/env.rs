//! The env's behaviour at its edges: bad actions and unstable physics end an episode with a typed
//! error (never a panic or a hang), and the env is deterministic.

use libero_e2e::bundles;
use libero_schema::Suite;
use libero_sim::SimError;
use libero_sim::env::LiberoEnv;

fn env() -> LiberoEnv {
    LiberoEnv::new(&bundles().load(Suite::LIBERO_OBJECT, 0).unwrap()).unwrap()
}

#[test]
fn non_finite_and_wrong_length_actions_are_typed_errors() {
    let mut env = env();
    assert!(env.step([0.0; 7]).unwrap_err().to_string().contains("reset"), "step before reset");
    env.reset(0, 7).unwrap();
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut a = [0.0; 7];
        a[2] = bad;
        assert!(matches!(env.step(a), Err(SimError::InvalidAction { .. })));
    }
    let err = env.step_slice(&[0.0; 6]).unwrap_err();
    assert!(matches!(err, SimError::InvalidAction { .. }) && err.to_string().contains("got 6"), "{err}");
    env.step_slice(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]).unwrap();
}

#[test]
fn an_exploding_state_is_an_unstable_error_not_a_panic() {
    let mut env = env();
    let bundle = env.bundle().clone();
    let mut state = bundle.init_state(0).unwrap().to_vec();
    let nq = bundle.task.init_states.nq;
    for v in &mut state[1 + nq..] {
        *v = 1e12;
    }
    env.reset_to(bundle.fixture_poses(7, 0).unwrap(), &state).unwrap();
    let err = env.step([0.0; 7]).unwrap_err();
    assert!(matches!(err, SimError::Unstable { .. }), "{err}");
}

#[test]
fn the_same_episode_gives_the_same_steps_bit_for_bit() {
    let run = || {
        let mut env = env();
        env.reset(3, 7).unwrap();
        for t in 0..30 {
            let x = (t as f64 * 0.3).sin();
            env.step([x, -x, 0.5 * x, 0.1, 0.0, -0.1, if t % 10 < 5 { -1.0 } else { 1.0 }]).unwrap();
        }
        env.state()
    };
    assert_eq!(run(), run());
}

#[test]
fn wait_steps_keep_the_scene_still_and_the_goal_unsatisfied() {
    let mut env = env();
    let start = env.reset(0, 7).unwrap();
    assert!(!start.satisfied);
    let before = env.observation();
    for _ in 0..libero_schema::protocol::NUM_STEPS_WAIT {
        let out = env.step(libero_schema::protocol::WAIT_ACTION.map(f64::from)).unwrap();
        assert!(!out.goal.satisfied);
    }
    let after = env.observation();
    let moved = (0..3).map(|i| (after.eef_pos[i] - before.eef_pos[i]).abs()).fold(0.0, f64::max);
    assert!(moved < 0.02, "the arm should barely move during wait steps ({moved} m)");
}
