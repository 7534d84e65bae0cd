//! One Python host process: started from the interpreter the user named, spoken to over its
//! stdin/stdout in [`Frame`]s, every exchange under a deadline.
//!
//! A reader thread decodes the host's stdout into a channel and a writer thread feeds its stdin,
//! so a host that hangs (a deadlock in the policy, a GPU stuck) costs at most the deadline: the
//! caller stops waiting, kills the process, and the threads end on the closed pipes. The host's
//! stderr (the policy's logs, Python's tracebacks) is passed on to ours line by line, prefixed
//! with the host's label, and its last lines are kept for the error of a host that died.

use super::frames::Frame;
use std::collections::VecDeque;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// How to start a host: `interpreter script args...`.
#[derive(Debug, Clone)]
pub struct HostCommand {
    pub interpreter: PathBuf,
    pub script: PathBuf,
    pub args: Vec<String>,
    /// Names the host in our stderr and in errors (`lerobot cuda:0`).
    pub label: String,
}

/// Lines of the host's stderr kept for an error message.
const STDERR_TAIL: usize = 30;

pub struct HostProcess {
    child: Child,
    to_host: Option<Sender<Vec<u8>>>,
    from_host: Receiver<Result<Frame, String>>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    label: String,
}

impl HostProcess {
    /// Starts the host and waits (up to `load_timeout`) for its first frame: `ready` with the
    /// policy's description, or the error that kept the policy from loading.
    pub fn start(command: &HostCommand, load_timeout: Duration) -> Result<(HostProcess, Frame), String> {
        let mut child = Command::new(&command.interpreter)
            .arg("-u")
            .arg(&command.script)
            .args(&command.args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                format!(
                    "cannot start the Python interpreter {}: {e}; name an interpreter that exists with ?python=/path/to/bin/python or LIBERO_EVAL_PYTHON",
                    command.interpreter.display()
                )
            })?;
        let (stdin, stdout, stderr) =
            (child.stdin.take().unwrap(), child.stdout.take().unwrap(), child.stderr.take().unwrap());

        let (to_host, writes) = channel::<Vec<u8>>();
        std::thread::spawn(move || {
            use std::io::Write;
            let mut stdin = stdin;
            for bytes in writes {
                if stdin.write_all(&bytes).and_then(|_| stdin.flush()).is_err() {
                    break;
                }
            }
        });
        let (replies, from_host) = channel();
        std::thread::spawn(move || {
            let mut stdout = BufReader::new(stdout);
            loop {
                let frame = match Frame::read_from(&mut stdout) {
                    Ok(Some(f)) => Ok(f),
                    Ok(None) => Err("it closed its output".to_string()),
                    Err(e) => Err(format!("its output is not a frame: {e}")),
                };
                let end = frame.is_err();
                if replies.send(frame).is_err() || end {
                    break;
                }
            }
        });
        let stderr_tail = Arc::new(Mutex::new(VecDeque::new()));
        let (tail, label) = (stderr_tail.clone(), command.label.clone());
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[python host {label}] {line}");
                let mut t = tail.lock().unwrap();
                if t.len() == STDERR_TAIL {
                    t.pop_front();
                }
                t.push_back(line);
            }
        });
        let mut host =
            HostProcess { child, to_host: Some(to_host), from_host, stderr_tail, label: command.label.clone() };
        let first = host.receive(load_timeout, "loading the policy")?;
        match first.op() {
            "ready" => Ok((host, first)),
            "error" => {
                let message = first.header.get("message").and_then(|m| m.as_str()).unwrap_or("").trim_end();
                Err(format!("the policy could not be loaded:\n{message}"))
            }
            other => Err(host.fail(format!("its first frame is {other:?}, expected \"ready\""))),
        }
    }

    /// Sends `frame` and waits up to `timeout` for the reply. After an error the host is dead
    /// (killed) and must be replaced.
    pub fn request(&mut self, frame: &Frame, timeout: Duration, during: &str) -> Result<Frame, String> {
        let sent = self.to_host.as_ref().map(|tx| tx.send(frame.encode()).is_ok()).unwrap_or(false);
        if !sent {
            return Err(self.fail(format!("its input is closed ({during})")));
        }
        self.receive(timeout, during)
    }

    fn receive(&mut self, timeout: Duration, during: &str) -> Result<Frame, String> {
        match self.from_host.recv_timeout(timeout) {
            Ok(Ok(frame)) => Ok(frame),
            Ok(Err(e)) => Err(self.fail(format!("{e} ({during})"))),
            Err(RecvTimeoutError::Timeout) => {
                Err(self.fail(format!("no answer within {:.0} s ({during}); killed", timeout.as_secs_f64())))
            }
            Err(RecvTimeoutError::Disconnected) => Err(self.fail(format!("it stopped ({during})"))),
        }
    }

    /// Kills the host and describes what happened: how it ended and its last stderr lines.
    fn fail(&mut self, what: String) -> String {
        self.to_host = None;
        let _ = self.child.kill();
        let status = self.child.wait().map(|s| s.to_string()).unwrap_or_else(|e| e.to_string());
        // The stderr thread may still be draining the pipe's last lines.
        std::thread::sleep(Duration::from_millis(50));
        let tail: Vec<String> = self.stderr_tail.lock().unwrap().iter().cloned().collect();
        let mut message = format!("the Python host {} failed: {what}; it ended with {status}", self.label);
        if !tail.is_empty() {
            message.push_str(&format!("; its last stderr lines:\n{}", tail.join("\n")));
        }
        message
    }
}

impl Drop for HostProcess {
    /// Closes the host's input (it exits at end of input) and reaps it; one that does not exit
    /// within 5 s is killed.
    fn drop(&mut self) {
        self.to_host = None;
        for _ in 0..100 {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
