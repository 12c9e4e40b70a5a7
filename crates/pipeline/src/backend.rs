//! The semantic back end: a thread that owns the network and labels snapshots of the map's
//! surface sent by the front end, so that tracking and fusion never wait for it (in real-time
//! mode) and the network runs beside them.
//!
//! A job carries everything the pass needs (coarse cells of the map frame with mean positions
//! and colours, and the gravity-aligned frame), so the result depends only on the job: the
//! front end decides when jobs are made and when results are applied, and with that the
//! pipeline's determinism.
//!
//! The back end has its own rayon pool, and on Linux its threads run at a lower scheduling
//! priority: on the global pool, the front end's parallel stages queued behind the network's
//! tasks (a worker drains its own deque before it takes injected work), and with two cores
//! the front end, which must keep up with the camera, should get the CPU first while the
//! network fills the gaps. Results do not change: the pool has as many threads as the
//! global one, and the network's output does not depend on the thread count anyway.

use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;
use std::time::Instant;

use glam::{Affine3A, Vec3};
use semrecon_net::{color_features, Segmenter};
use semrecon_sparse::voxelize::voxelize;

use crate::error::{PipelineError, Result};
use crate::semantic_map::{CellKey, CLASSES};

/// One semantic pass to run.
#[derive(Debug, Clone)]
pub(crate) struct Job {
    /// Keys of the input cells.
    pub keys: Vec<CellKey>,
    /// Mean positions of the cells, map frame.
    pub positions: Vec<Vec3>,
    /// Mean colours.
    pub colors: Vec<[u8; 3]>,
    /// Whether each cell's labels are written back (the others are context).
    pub update: Vec<bool>,
    /// Map to the frame the network expects (z up, floor at 0).
    pub aligned_from_map: Affine3A,
}

/// The outcome of a [`Job`].
#[derive(Debug, Clone)]
pub(crate) struct JobResult {
    /// The cells whose labels are written back.
    pub keys: Vec<CellKey>,
    /// Their class probabilities.
    pub probs: Vec<[f32; CLASSES]>,
    /// Their mean colours as the pass saw them.
    pub colors: Vec<[u8; 3]>,
    /// Voxels the network saw (cells merged by the aligned grid).
    pub network_voxels: usize,
    /// Wall time of voxelising, the network and the softmax, milliseconds.
    pub total_ms: f64,
}

/// Voxelises a job in the aligned frame, runs the network, and returns the probabilities of
/// the cells to update (each cell takes its aligned voxel's).
pub(crate) fn run_job(net: &mut Segmenter, job: Job) -> Result<JobResult> {
    let t = Instant::now();
    let size = net.config().voxel_size;
    let aligned: Vec<[f32; 3]> =
        job.positions.iter().map(|p| job.aligned_from_map.transform_point3(*p).to_array()).collect();
    if let Some(i) = aligned.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(PipelineError::Backend(format!("cell {} has a non-finite position", job.keys[i])));
    }
    // The engine's voxelisation averages the cells' colours per network voxel and keeps the
    // cell-to-voxel map; its voxels come out in the order the network wants.
    let voxels = voxelize(&aligned, &color_features(&job.colors), 3, size, 0).map_err(semrecon_net::NetError::from)?;
    let voxel_of = voxels.point_to_voxel;
    let (coords, features) = voxels.tensor.into_parts();
    let logits = if coords.is_empty() { Vec::new() } else { net.segment(&coords, &features)? };
    let classes = net.config().classes;
    let probs_of = |v: usize| -> [f32; CLASSES] {
        let row = &logits[v * classes..(v + 1) * classes];
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut p = [0f32; CLASSES];
        let mut sum = 0.0;
        for (o, &l) in p.iter_mut().zip(row) {
            *o = (l - max).exp();
            sum += *o;
        }
        p.iter_mut().for_each(|o| *o /= sum);
        p
    };
    let mut keys = Vec::new();
    let mut probs = Vec::new();
    let mut colors = Vec::new();
    for (i, &u) in job.update.iter().enumerate() {
        if u {
            keys.push(job.keys[i]);
            probs.push(probs_of(voxel_of[i] as usize));
            colors.push(job.colors[i]);
        }
    }
    Ok(JobResult { keys, probs, colors, network_voxels: coords.len(), total_ms: t.elapsed().as_secs_f64() * 1e3 })
}

/// What the front end asks of the back-end thread.
enum Request {
    /// A pass to run; its result comes back on the results channel.
    Pass(Job),
    /// Free the network's work buffers (no result): the scan is over.
    ReleaseWorkspace,
}

/// The back-end thread and its two channels.
pub(crate) struct Backend {
    jobs: Option<Sender<Request>>,
    results: Receiver<Result<JobResult>>,
    handle: Option<JoinHandle<()>>,
}

impl Backend {
    /// Starts the thread, which owns `net`, and its pool.
    pub fn start(mut net: Segmenter) -> Result<Self> {
        let (job_tx, job_rx) = channel::<Request>();
        let (res_tx, res_rx) = channel::<Result<JobResult>>();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name(|i| format!("semantic worker {i}"))
            .start_handler(|_| lower_priority())
            .build()
            .map_err(|e| PipelineError::Backend(format!("cannot start the worker pool: {e}")))?;
        let handle = std::thread::Builder::new()
            .name("semantic back end".into())
            .spawn(move || {
                lower_priority();
                for request in job_rx {
                    match request {
                        Request::Pass(job) => {
                            if res_tx.send(pool.install(|| run_job(&mut net, job))).is_err() {
                                break;
                            }
                        }
                        Request::ReleaseWorkspace => {
                            net.release_workspace();
                            crate::freed_memory::return_to_os();
                        }
                    }
                }
            })
            .map_err(|e| PipelineError::Backend(format!("cannot start the thread: {e}")))?;
        Ok(Self { jobs: Some(job_tx), results: res_rx, handle: Some(handle) })
    }

    /// Hands a job to the thread.
    pub fn submit(&self, job: Job) -> Result<()> {
        self.send(Request::Pass(job))
    }

    /// Asks the thread to free the network's work buffers once the job in hand is done (the
    /// end of a scan; a later job allocates them again).
    pub fn release_workspace(&self) -> Result<()> {
        self.send(Request::ReleaseWorkspace)
    }

    fn send(&self, request: Request) -> Result<()> {
        self.jobs
            .as_ref()
            .ok_or_else(|| PipelineError::Backend("already stopped".into()))?
            .send(request)
            .map_err(|_| PipelineError::Backend("the thread has exited".into()))
    }

    /// Waits for the next result.
    pub fn wait(&self) -> Result<JobResult> {
        self.results.recv().map_err(|_| PipelineError::Backend("the thread has exited".into()))?
    }

    /// The next result if one is ready.
    pub fn poll(&self) -> Option<Result<JobResult>> {
        match self.results.try_recv() {
            Ok(r) => Some(r),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err(PipelineError::Backend("the thread has exited".into()))),
        }
    }
}

/// Niceness of the back end's threads (0 is the front end's; 19 the lowest priority). Not
/// the lowest: on a loaded machine the network must still make progress.
#[cfg(target_os = "linux")]
const BACKEND_NICENESS: i32 = 10;

/// CPU time the calling thread has used, ms; `None` where the platform does not say. The
/// back end's threads yield to the front end, so their wall time says how long a result
/// takes to come back on a busy machine, and this what it costs.
pub(crate) fn thread_cpu_ms() -> Option<f64> {
    #[cfg(unix)]
    {
        let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: `clock_gettime` writes only the `timespec` it is given.
        let ok = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) } == 0;
        ok.then_some(t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6)
    }
    #[cfg(not(unix))]
    {
        None
    }
}

/// Lowers the calling thread's scheduling priority (Linux gives each thread its own nice
/// value); elsewhere, and where the call fails, the thread keeps its priority, which changes
/// timings only.
pub(crate) fn lower_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `gettid` has no preconditions; `setpriority` on a thread id only reads its
        // arguments.
        unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, BACKEND_NICENESS);
        }
    }
}

impl Drop for Backend {
    fn drop(&mut self) {
        // Closing the job channel ends the thread's loop after the job in hand.
        self.jobs.take();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
