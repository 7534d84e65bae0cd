//! GL contexts as threads that render for the rollout workers: a GL thread of its own for each
//! worker (the default), or one shared GL thread per GPU for all the workers of the process
//! (`LIBERO_GL_THREADS=shared`, [`GL_THREADS`]).
//!
//! Why a shared thread: on the NVIDIA driver a process's GL contexts do not render side by side,
//! they get in each other's way (`data/benchmarks/gpu-render-threads-2026-11-27`, `pipeline bench
//! render`). On an H100 one context renders 158 camera pairs/s; 2 contexts in two threads of one
//! process 105 pairs/s in all, 4 contexts 45, 16 contexts 31 (the driver's `__GL_YIELD` and
//! `__GL_THREADED_OPTIMIZATIONS` change nothing), while 4 separate processes render ~570 pairs/s.
//! On an H200, 16 threads with a context each rendered 36 pairs/s and 16 or 64 threads through
//! one shared GL thread 293 and 311; a run's 64 workers made 48.2 OpenVLA steps/s through it
//! against 38.8 with a context each.
//!
//! Why not the default yet: those shared-thread runs predate [`crate::render::SceneRenderer`]
//! binding its own framebuffer before each draw, without which a draw after another renderer's
//! went into that renderer's buffer (`tests/render.rs` catches it on Mesa); and a variant that
//! kept each worker's renderer across its episodes hung on the GPU, cause not found. Until a GPU
//! run checks the frames and the speed again, workers render on a GL thread each, as before.
//!
//! On Mesa's software device (llvmpipe: CPU machines, CI) renders are CPU work that contexts in
//! separate threads do in parallel: a thread each is right there in any case.
//!
//! A render is a blocking call: the worker hands its GL thread a closure that borrows its env and
//! its renderer ([`GlThread::call`]) and waits for the frame. Things made on a GL thread that need
//! its context, such as a [`crate::render::SceneRenderer`], live in an [`OnGlThread`] that uses
//! and drops them there.

use crate::SimError;
use crate::gl::{DeviceInfo, GlContext};
use std::collections::HashMap;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::rc::Rc;
use std::sync::mpsc::{Sender, channel, sync_channel};
use std::sync::{Arc, Mutex};

/// Work for the GL thread; the lifetime is erased by [`GlThread::call`], which waits for it.
type Job = Box<dyn FnOnce(&Rc<GlContext>) + Send + 'static>;
/// A [`Job`] before [`GlThread::call`] erases its lifetime: borrowing the caller's state.
type BorrowingJob<'a> = Box<dyn FnOnce(&Rc<GlContext>) + 'a>;

/// A thread holding one current GL context, running the renders it is handed in turn.
pub struct GlThread {
    jobs: Sender<Job>,
    device: Option<DeviceInfo>,
}

/// The variable that chooses between a GL thread for each worker (`per-worker`, the default) and
/// one GL thread per device for all the workers of the process (`shared`).
pub const GL_THREADS: &str = "LIBERO_GL_THREADS";

/// Whether [`GL_THREADS`] asks for shared GL threads; an error naming the values it takes for any
/// other value (`pipeline run` checks it before any episode).
pub fn shared_gl_threads() -> Result<bool, SimError> {
    match std::env::var(GL_THREADS).as_deref() {
        Ok("shared") => Ok(true),
        Ok("per-worker") | Err(_) => Ok(false),
        Ok(other) => Err(SimError::Other(format!(
            "{GL_THREADS}={other:?} is not a GL thread choice: set it to shared (one GL thread per GPU for all \
             workers) or per-worker (the default), or unset it"
        ))),
    }
}

/// The process's shared GL thread of each EGL device (`None`: the surfaceless platform).
static BY_DEVICE: Mutex<Option<HashMap<Option<usize>, Arc<GlThread>>>> = Mutex::new(None);

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
        std::thread::Builder::new()
            .name(name)
            .spawn(move || {
                let gl = match GlContext::on(device.as_ref()) {
                    Ok(gl) => Rc::new(gl),
                    Err(e) => return drop(ready.send(Err(e))),
                };
                let _ = ready.send(Ok(gl.device().cloned()));
                while let Ok(job) = queue.recv() {
                    job(&gl);
                }
            })
            .map_err(|e| SimError::Other(format!("cannot start a GL thread: {e}")))?;
        let device =
            started.recv().map_err(|_| SimError::Other("the GL thread ended while making its context".into()))??;
        Ok(Arc::new(GlThread { jobs, device }))
    }

    /// The GL thread a rollout worker renders on, on the device [`crate::gl::next_device`] gives
    /// it: a thread of its own, or with [`GL_THREADS`]`=shared` the device's one thread for the
    /// whole process (started on first use).
    pub fn for_worker() -> Result<Arc<GlThread>, SimError> {
        let shared = shared_gl_threads()?;
        let device = crate::gl::next_device()?;
        if !shared {
            return GlThread::start(device.as_ref());
        }
        let key = device.as_ref().map(|d| d.index);
        let mut map = BY_DEVICE.lock().expect("GL threads");
        let map = map.get_or_insert_with(HashMap::new);
        if let Some(thread) = map.get(&key) {
            return Ok(thread.clone());
        }
        let thread = GlThread::start(device.as_ref())?;
        map.insert(key, thread.clone());
        Ok(thread)
    }

    /// The EGL device its context is on.
    pub fn device(&self) -> Option<&DeviceInfo> {
        self.device.as_ref()
    }

    /// Run `job` on the GL thread with its context and wait for its result. A panic in `job` is
    /// resumed here.
    ///
    /// # Safety
    /// `job` runs on the GL thread while this thread waits, so what it borrows or owns must allow
    /// being used from another thread while its own thread is blocked: MuJoCo models and data,
    /// renderers made on this GL thread, plain buffers. Nothing tied to this thread's identity
    /// (a held lock's guard, this thread's GL context, thread-locals read through a capture).
    pub unsafe fn call<R>(&self, job: impl FnOnce(&Rc<GlContext>) -> R) -> R {
        let (reply, answer) = sync_channel(1);
        let job = move |gl: &Rc<GlContext>| {
            let _ = reply.send(catch_unwind(AssertUnwindSafe(|| job(gl))));
        };
        let job: BorrowingJob<'_> = Box::new(job);
        // SAFETY: this function returns only after the job has run (or was dropped unrun when the
        // thread is gone), so its borrows outlive every use; the caller vouches for the rest.
        let job: Job = unsafe { std::mem::transmute(job) };
        self.jobs.send(job).expect("the GL thread ended");
        match answer.recv() {
            Ok(Ok(value)) => value,
            Ok(Err(panic)) => resume_unwind(panic),
            Err(_) => panic!("the GL thread ended during a render"),
        }
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
    pub unsafe fn make<E>(thread: Arc<GlThread>, make: impl FnOnce(&Rc<GlContext>) -> Result<T, E>) -> Result<Self, E> {
        let value = unsafe { thread.call(make) }?;
        Ok(OnGlThread { value: Some(value), thread })
    }

    /// Use the value on its GL thread.
    ///
    /// # Safety
    /// As [`GlThread::call`] for `job`.
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
    fn calls_run_on_the_gl_thread_borrow_the_callers_state_and_resume_panics() {
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
    }
}
