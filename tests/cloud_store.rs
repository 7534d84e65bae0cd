//! A run stored on S3: `pipeline run --out s3://bucket/run` against an S3-compatible server on
//! localhost (moto's S3 server, from the venv of `scripts/setup/s3_server_venv.sh`), then
//! `results` and `sql` read it back, a second `run` resumes without re-running or duplicating, and
//! a missing bucket is an error naming it. The bucket is listed with boto3, independently of
//! object_store, and the S3 run's results equal those of the same run on a local disk.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, test_dir};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BUCKET: &str = "libero-runs";

fn s3_python() -> PathBuf {
    let venv = std::env::var_os("LIBERO_S3_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".s3-venv"));
    let py = venv.join("bin/python");
    assert!(
        py.exists(),
        "no S3 server venv at {}: run ./setup.sh --tests, or `bash scripts/setup/s3_server_venv.sh DIR` and set LIBERO_S3_VENV=DIR",
        venv.display()
    );
    py
}

/// moto's S3 server on a free port, stopped when dropped.
struct S3Server {
    child: Child,
    endpoint: String,
}

impl S3Server {
    fn start(log: &Path) -> S3Server {
        let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let child = Command::new(s3_python())
            .args(["-m", "moto.server", "-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .expect("start moto's S3 server");
        let mut server = S3Server { child, endpoint: format!("http://127.0.0.1:{port}") };
        let t0 = Instant::now();
        let log_tail =
            || std::fs::read_to_string(log).unwrap_or_default().lines().rev().take(20).collect::<Vec<_>>().join("\n");
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            if let Ok(Some(status)) = server.child.try_wait() {
                panic!("moto's S3 server exited ({status}):\n{}", log_tail());
            }
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "moto's S3 server did not listen within 30 s:\n{}",
                log_tail()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        // the listener is moto (not another program that took the port meanwhile)
        assert_eq!(server.boto3("print(len(s3.list_buckets()['Buckets']))").trim(), "0");
        server
    }

    /// Runs a boto3 snippet (`s3` is a client of this server) and returns its stdout.
    fn boto3(&self, code: &str) -> String {
        let script = format!(
            "import boto3\ns3 = boto3.client('s3', endpoint_url='{}', region_name='us-east-1', \
             aws_access_key_id='testing', aws_secret_access_key='testing')\n{code}",
            self.endpoint
        );
        let out = Command::new(s3_python()).args(["-c", &script]).output().unwrap();
        assert!(out.status.success(), "boto3: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// `pipeline` with this server's endpoint and credentials in the environment, as a user sets them.
    fn pipeline(&self, args: &[&str]) -> Output {
        let mut cmd = Command::new(pipeline_bin());
        // none of the developer's own AWS settings (AWS_ENDPOINT_URL, AWS_SESSION_TOKEN, a profile, ...)
        for (key, _) in std::env::vars().filter(|(k, _)| k.starts_with("AWS_")) {
            cmd.env_remove(key);
        }
        cmd.args(args)
            .current_dir(repo_root())
            .env("AWS_ENDPOINT", &self.endpoint)
            .env("AWS_ALLOW_HTTP", "true")
            .env("AWS_ACCESS_KEY_ID", "testing")
            .env("AWS_SECRET_ACCESS_KEY", "testing")
            .env("AWS_REGION", "us-east-1")
            .output()
            .expect("run pipeline")
    }

    fn keys(&self, prefix: &str) -> Vec<String> {
        let out = self.boto3(&format!(
            "for o in s3.list_objects_v2(Bucket='{BUCKET}', Prefix='{prefix}').get('Contents', []): print(o['Key'])"
        ));
        let mut keys: Vec<String> = out.lines().map(str::to_string).collect();
        keys.sort();
        keys
    }
}

impl Drop for S3Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn a_run_on_s3_is_written_read_resumed_and_equals_the_local_run() {
    let d = test_dir("cloud", "s3");
    let server = S3Server::start(&d.join("moto.log"));
    server.boto3(&format!("s3.create_bucket(Bucket='{BUCKET}')"));

    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "1", "-o", s]));
    let run = format!("s3://{BUCKET}/lift");
    let args = ["run", s, "--out", &run, "--policy", "lift", "--max-steps", "5"];
    let first = ok(server.pipeline(&args));
    assert!(first.contains("libero_spatial"), "the run prints its results: {first}");

    // what object_store wrote, seen through boto3: manifest, specs, one steps and one episodes part per episode
    let keys = server.keys("lift/");
    let count =
        |dir: &str| keys.iter().filter(|k| k.starts_with(&format!("lift/{dir}/")) && k.ends_with(".parquet")).count();
    assert!(
        keys.contains(&"lift/manifest.json".to_string()) && keys.contains(&"lift/specs.parquet".to_string()),
        "{keys:?}"
    );
    assert_eq!((count("steps"), count("episodes")), (2, 2), "{keys:?}");

    // a second run of the same command resumes: nothing re-run, nothing duplicated
    let again = server.pipeline(&args);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success() && stderr.contains("2 already finished, 0 to run"), "{stderr}");
    assert_eq!(server.keys("lift/"), keys);

    // SQL and results read the run from S3, and equal the same run on a local disk
    let local = d.join("local");
    ok(pipeline(&["run", s, "--out", local.to_str().unwrap(), "--policy", "lift", "--max-steps", "5"]));
    let query = "SELECT episode_key, count(*), sum(eef_pos[3]) FROM steps GROUP BY episode_key ORDER BY episode_key";
    let on_s3 = ok(server.pipeline(&["sql", query, "--run", &run, "--csv"]));
    assert_eq!(on_s3, ok(pipeline(&["sql", query, "--run", local.to_str().unwrap(), "--csv"])));
    assert_eq!(on_s3.lines().count(), 3, "{on_s3}");
    for (name, location) in [("s3", run.as_str()), ("local", local.to_str().unwrap())] {
        ok(server.pipeline(&["results", "--run", location, "--out", d.join(name).to_str().unwrap()]));
    }
    let results = |name: &str| std::fs::read_to_string(d.join(name).join("results.csv")).unwrap();
    assert_eq!(results("s3"), results("local"));

    // a bucket that does not exist: an error naming it and the fix, before any episode, for a run
    // and for reading one
    let says = |t: &str| {
        t.contains("the bucket \"no-such-bucket\" does not exist at http://127.0.0.1") && t.contains("create it")
    };
    let missing =
        server.pipeline(&["run", s, "--out", "s3://no-such-bucket/run", "--policy", "lift", "--max-steps", "5"]);
    let text = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success() && says(&text), "{text}");
    let missing =
        server.pipeline(&["results", "--run", "s3://no-such-bucket/run", "--out", d.join("none").to_str().unwrap()]);
    let text = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success() && says(&text), "{text}");
}
