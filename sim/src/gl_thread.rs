//! GL contexts as threads that render for the rollout workers: one shared GL thread, on one GPU,
//! for all the workers of the process (the default on hardware devices), or a GL thread of its own
//! for each worker (the default on Mesa's software device); [`GlThreads`], `LIBERO_GL_THREADS`.
//!
//! Why a shared thread on a GPU: on the NVIDIA driver a process's GL contexts do not render side
//! by side, they get in each other's way (`data/benchmarks/gpu-render-threads-2026-11-27`,
//! `pipeline bench render`). On an H100 one context renders 158 camera pairs/s; 2 contexts in two
//! threads of one process 105 pairs/s in all, 4 contexts 45, 16 contexts 31 (the driver's
//! `__GL_YIELD` and `__GL_THREADED_OPTIMIZATIONS` change nothing), while 4 separate processes
//! render ~570 pairs/s. Through one shared GL thread, 4/16/64 threads render 311/250/278 pairs/s on
//! an H100, against 40 for 16 threads with a context each, every thread's frames bit for bit those
//! of a context of its own; a run's 64 workers made 40.9 OpenVLA steps/s through it against 31.6
//! with a context each (`data/benchmarks/gpu-gl-threads-h100-2026-11-27`).
//!
//! Why one thread for the process, not one per GPU: two shared GL threads of one process, on two
//! H100s, rendered 65 camera pairs/s in all with 64 worker threads, against 282 and 288 pairs/s
//! for one thread on either GPU; a run with replicas on both GPUs made 80.9 OpenVLA steps/s
//! with its renders through one thread, 73.3 through a thread per GPU
//! (`data/benchmarks/gpu-two-h100-one-gl-thread-2026-11-27`). The driver serialises a process's
//! contexts whichever GPUs they are on; one thread keeps a single context busy instead.
//!
//! On Mesa's software device (llvmpipe: CPU machines, CI) renders are CPU work that contexts in
//! separate threads do in parallel: a thread each is right there.
//!
//! A render is a blocking call: the worker hands its GL thread a closure that borrows its env and
//! its renderer ([`GlThread::call`]) and waits for the frame. Things made on a GL thread that need
//! its context, such as a [`crate::render::SceneRenderer`], live in an [`OnGlThread`] that uses
//! and drops them there. Several renderers share one GL context this way; each binds its own
//! framebuffer before it draws or reads.

use crate::SimError;
use crate::gl::{DeviceInfo, GlContext};
use std::cell::RefCell;
use std::panic::{AssertUnwindSafe, Location, catch_unwind, resume_unwind};
use std::rc::Rc;
use std::sync::mpsc::{RecvTimeoutError, Sender, channel, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::ThreadId;
use std::time::{Duration, Instant};

/// Work for the GL thread; the lifetime is erased by [`GlThread::call`], which waits for it.
type Job = Box<dyn FnOnce(&Rc<GlContext>) + Send + 'static>;
/// A [`Job`] before [`GlThread::call`] erases its lifetime: borrowing the caller's state.
type BorrowingJob<'a> = Box<dyn FnOnce(&Rc<GlContext>) + 'a>;

/// A thread holding one current GL context, running the renders it is handed in turn.
pub struct GlThread {
    jobs: Sender<Job>,
    device: Option<DeviceInfo>,
    /// The GL thread's own id: a call made from the GL thread itself (a job that drops an
    /// [`OnGlThread`], say) runs in place instead of waiting on its own queue forever.
    thread: ThreadId,
    /// The job the GL thread is running: where it was handed over, and since when. A worker that
    /// has waited [`WAIT_WARNING`] says so and names it, so a stuck render is found, not guessed.
    running: Arc<Mutex<Option<(&'static Location<'static>, Instant)>>>,
}

/// How long a worker waits for the GL thread before it says what the GL thread is doing (and
/// again after each further period). With 64 workers starting together, the first renders wait
/// ~25 s behind the scene uploads on a GPU; minutes mean something is stuck.
const WAIT_WARNING: Duration = Duration::from_secs(120);

thread_local! {
    /// On a GL thread: its context, for calls made from the GL thread itself.
    static OWN_CONTEXT: RefCell<Option<Rc<GlContext>>> = const { RefCell::new(None) };
}

/// The variable that chooses how workers get their GL threads ([`GlThreads`]): `shared`,
/// `per-worker`, or unset (`auto`).
pub const GL_THREADS: &str = "LIBERO_GL_THREADS";

/// How the rollout workers of a process get their GL threads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GlThreads {
    /// A GL thread for each worker.
    PerWorker,
    /// One GL thread for all the workers of the process, on the device its first worker's context
    /// would take (a GPU without a model where there is one).
    Shared,
    /// The default: shared on a hardware device (a GPU's contexts slow each other down), a thread
    /// each on Mesa's software device (its contexts render on the CPU's cores side by side).
    Auto,
}

impl GlThreads {
    /// The choice [`GL_THREADS`] makes; an error naming the values it takes for any other value
    /// (`pipeline run` checks it before any episode).
    pub fn from_env() -> Result<GlThreads, SimError> {
        match std::env::var(GL_THREADS).as_deref() {
            Ok("shared") => Ok(GlThreads::Shared),
            Ok("per-worker") => Ok(GlThreads::PerWorker),
            Ok("auto") | Err(_) => Ok(GlThreads::Auto),
            Ok(other) => Err(SimError::Other(format!(
                "{GL_THREADS}={other:?} is not a GL thread choice: set it to shared (one GL thread for all workers), \
                 per-worker (a GL thread each) or auto (shared on GPUs, per-worker on the CPU: the default), \
                 or unset it"
            ))),
        }
    }

    /// Whether workers rendering on `device` (`None`: Mesa's surfaceless platform) share its thread.
    pub fn shared_on(self, device: Option<&DeviceInfo>) -> bool {
        match self {
            GlThreads::PerWorker => false,
            GlThreads::Shared => true,
            GlThreads::Auto => device.is_some_and(|d| !d.software),
        }
    }
}

/// The process's shared GL thread, once a worker has started it.
static SHARED: Mutex<Option<Arc<GlThread>>> = Mutex::new(None);

impl GlThread {
    /// Start a thread with a new GL context on `device` (`None`: Mesa's surfaceless platform).
    /// The thread ends when the last handle is dropped.
    pub fn start(device: Option<&DeviceInfo>) -> Result<Arc<GlThread>, SimError> {
        let (jobs, queue) = channel::<Job>();
        let (ready, started) = sync_channel(1);
        let device = device.cloned();
        let name = match &device {
            Some(d) => format!("gl-device-{}", d.index),
            None => "gl".into(),
        };
        let handle = std::thread::Builder::new()
            .name(name)
            .spawn(move || {
                let gl = match GlContext::on(device.as_ref()) {
                    Ok(gl) => Rc::new(gl),
                    Err(e) => return drop(ready.send(Err(e))),
                };
                OWN_CONTEXT.with(|own| *own.borrow_mut() = Some(gl.clone()));
                let _ = ready.send(Ok(gl.device().cloned()));
                while let Ok(job) = queue.recv() {
                    job(&gl);
                }
                OWN_CONTEXT.with(|own| own.borrow_mut().take());
            })
            .map_err(|e| SimError::Other(format!("cannot start a GL thread: {e}")))?;
        let device =
            started.recv().map_err(|_| SimError::Other("the GL thread ended while making its context".into()))??;
        Ok(Arc::new(GlThread { jobs, device, thread: handle.thread().id(), running: Arc::default() }))
    }

    /// The GL thread a rollout worker renders on: where [`GlThreads`] shares them, the process's
    /// one thread (started on first use, on the device [`crate::gl::next_device`] gives it), else a
    /// thread of its own on the device `next_device` gives it.
    pub fn for_worker() -> Result<Arc<GlThread>, SimError> {
        let choice = GlThreads::from_env()?;
        let started = SHARED.lock().expect("the shared GL thread").clone();
        if let Some(thread) = started.filter(|t| choice.shared_on(t.device())) {
            return Ok(thread);
        }
        let device = crate::gl::next_device()?;
        if !choice.shared_on(device.as_ref()) {
            // a thread of its own, made without holding the lock: workers start theirs side by side
            return GlThread::start(device.as_ref());
        }
        let mut shared = SHARED.lock().expect("the shared GL thread");
        if let Some(thread) = shared.as_ref() {
            return Ok(thread.clone()); // another worker started it meanwhile
        }
        let thread = GlThread::start(device.as_ref())?;
        *shared = Some(thread.clone());
        Ok(thread)
    }

    /// The EGL device its context is on.
    pub fn device(&self) -> Option<&DeviceInfo> {
        self.device.as_ref()
    }

    /// Run `job` on the GL thread with its context and wait for its result. A panic in `job` is
    /// resumed here. Called on the GL thread itself, `job` runs in place.
    ///
    /// # Safety
    /// `job` runs on the GL thread while this thread waits, so what it borrows or owns must allow
    /// being used from another thread while its own thread is blocked: MuJoCo models and data,
    /// renderers made on this GL thread, plain buffers. Nothing tied to this thread's identity
    /// (a held lock's guard, this thread's GL context, thread-locals read through a capture).
    #[track_caller]
    pub unsafe fn call<R>(&self, job: impl FnOnce(&Rc<GlContext>) -> R) -> R {
        if std::thread::current().id() == self.thread {
            let gl = OWN_CONTEXT.with(|own| own.borrow().clone()).expect("a GL thread holds its context");
            return job(&gl);
        }
        let caller = Location::caller();
        let (reply, answer) = sync_channel(1);
        let running = self.running.clone();
        let job = move |gl: &Rc<GlContext>| {
            *running.lock().expect("GL job label") = Some((caller, Instant::now()));
            let result = catch_unwind(AssertUnwindSafe(|| job(gl)));
            *running.lock().expect("GL job label") = None;
            let _ = reply.send(result);
        };
        let job: BorrowingJob<'_> = Box::new(job);
        // SAFETY: this function returns only after the job has run (or was dropped unrun when the
        // thread is gone), so its borrows outlive every use; the caller vouches for the rest.
        let job: Job = unsafe { std::mem::transmute(job) };
        self.jobs.send(job).expect("the GL thread ended");
        let asked = Instant::now();
        loop {
            match answer.recv_timeout(WAIT_WARNING) {
                Ok(Ok(value)) => return value,
                Ok(Err(panic)) => resume_unwind(panic),
                Err(RecvTimeoutError::Timeout) => self.warn_of_a_long_wait(caller, asked.elapsed()),
                Err(RecvTimeoutError::Disconnected) => panic!("the GL thread ended during a render"),
            }
        }
    }

    /// Say on stderr that the job handed over at `caller` has waited `waited`, and what the GL
    /// thread is running.
    fn warn_of_a_long_wait(&self, caller: &Location, waited: Duration) {
        let device =
            self.device.as_ref().map_or("the surfaceless platform".to_string(), |d| format!("EGL device {}", d.index));
        let running = match *self.running.lock().expect("GL job label") {
            Some((at, since)) => format!("the job handed over at {at}, for {:.0} s", since.elapsed().as_secs_f64()),
            None => "nothing at this moment (its queue moves)".to_string(),
        };
        eprintln!(
            "libero-sim: a job handed to the GL thread of {device} at {caller} has waited {:.0} s; that thread is running {running}",
            waited.as_secs_f64()
        );
    }
}

/// A value made on a GL thread that needs its context (a render context, say): used only there,
/// dropped there, owned by a worker.
pub struct OnGlThread<T> {
    value: Option<T>,
    thread: Arc<GlThread>,
}

// SAFETY: the value is only touched on its GL thread, through `call`, while the owner waits.
unsafe impl<T> Send for OnGlThread<T> {}

impl<T> OnGlThread<T> {
    /// Make the value on `thread`.
    ///
    /// # Safety
    /// As [`GlThread::call`] for `make`.
    #[track_caller]
    pub unsafe fn make<E>(thread: Arc<GlThread>, make: impl FnOnce(&Rc<GlContext>) -> Result<T, E>) -> Result<Self, E> {
        let value = unsafe { thread.call(make) }?;
        Ok(OnGlThread { value: Some(value), thread })
    }

    /// Use the value on its GL thread.
    ///
    /// # Safety
    /// As [`GlThread::call`] for `job`.
    #[track_caller]
    pub unsafe fn with<R>(&mut self, job: impl FnOnce(&mut T) -> R) -> R {
        let value = self.value.as_mut().expect("present until dropped");
        unsafe { self.thread.call(|_| job(value)) }
    }
}

impl<T> Drop for OnGlThread<T> {
    fn drop(&mut self) {
        let value = self.value.take();
        // SAFETY: the value was made on this thread and is dropped there.
        unsafe { self.thread.call(move |_| drop(value)) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn by_default_workers_share_the_process_gl_thread_on_a_gpu_and_get_one_each_on_the_cpu() {
        let device = |software| DeviceInfo { index: 0, software, drm_file: None, cuda: None };
        let (gpu, mesa) = (device(false), device(true));
        assert!(GlThreads::Auto.shared_on(Some(&gpu)));
        assert!(!GlThreads::Auto.shared_on(Some(&mesa)));
        assert!(!GlThreads::Auto.shared_on(None)); // Mesa's surfaceless platform
        assert!(GlThreads::Shared.shared_on(None) && GlThreads::Shared.shared_on(Some(&mesa)));
        assert!(!GlThreads::PerWorker.shared_on(Some(&gpu)));
    }

    #[test]
    fn calls_run_on_the_gl_thread_borrow_the_callers_state_resume_panics_and_nest() {
        let thread = GlThread::start(crate::gl::next_device().unwrap().as_ref()).unwrap();
        let caller = std::thread::current().id();
        let mut seen = Vec::new();
        let on = unsafe {
            thread.call(|_| {
                seen.push(1);
                std::thread::current().id()
            })
        };
        assert_ne!(on, caller);
        assert_eq!(seen, [1]);
        let panic = catch_unwind(AssertUnwindSafe(|| unsafe { thread.call(|_| panic!("in a render")) }));
        assert!(panic.is_err());
        // the thread survives a job's panic
        assert_eq!(unsafe { thread.call(|_| 7) }, 7);
        let mut value = unsafe { OnGlThread::make(thread.clone(), |_| Ok::<_, ()>(vec![1])) }.unwrap();
        unsafe { value.with(|v| v.push(2)) };
        assert_eq!(unsafe { value.with(|v| v.clone()) }, [1, 2]);
        // a call from the GL thread itself (a job that drops a value of that thread's) runs in
        // place instead of waiting on its own queue
        let inner = unsafe { OnGlThread::make(thread.clone(), |_| Ok::<_, ()>(5)) }.unwrap();
        let on_gl_thread = unsafe {
            thread.call(move |_| {
                drop(inner);
                std::thread::current().id()
            })
        };
        assert_eq!(on_gl_thread, on);
    }
}
