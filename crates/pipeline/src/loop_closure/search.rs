//! The loop search and the pose-graph optimisation of a keyframe, on a back-end thread.
//!
//! At a keyframe the front end hands the keyframe database and a copy of the pose graph
//! ([`GraphWork`]) to a thread of its own, and goes on tracking and fusing; it takes the
//! result back at the next keyframe, before that keyframe joins the graph, and the trajectory
//! and the map follow a correction found there. The search (a few candidate ICPs, about a
//! millisecond each) and the optimisation (milliseconds, tens on a two-minute graph) then
//! cost the front end nothing but the hand-over, unless the thread is still busy a keyframe
//! later (a wait, within the front end's `loop closure` stage). Taking the result at a frame
//! count, never at a time, keeps the output the same for any thread count and any machine
//! load: the search reads only what it was handed.
//!
//! The thread runs its parallel parts in a pool of its own, as the semantic back end does:
//! the front end may itself be a worker of a one-thread pool, and a search queued behind it
//! would never run while the front end waits for it.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;
use std::time::Instant;

use glam::DAffine3;
use semrecon_data::Frame;
use semrecon_recon::pose_graph::{alignment_information, isotropic_information, OptimisationReport};
use semrecon_recon::{EdgeKind, LoopDetector, LoopVerdict, PoseEdge, PoseGraph};

use super::{moved_by, LoopClosureConfig, LoopRecord, MAX_ODOMETRY_SCALE};
use crate::error::{PipelineError, Result};

/// What a search works on, owned by the thread while it runs: the keyframe database, the
/// keyframes to add to it, and a copy of the graph (the front end keeps its own to read
/// meanwhile).
pub(super) struct GraphWork {
    pub detector: LoopDetector,
    /// Keyframes to add to the database first (their graph nodes exist already).
    pub new_keyframes: Vec<Frame>,
    pub graph: PoseGraph,
    /// How many times `odometry_sigma` the odometry's standard deviations are (see
    /// [`GraphWork::retry_with_looser_odometry`]).
    pub odometry_scale: f64,
}

/// A correction of the keyframe poses found by a search.
#[derive(Debug, Clone, Copy)]
pub(super) struct GraphCorrection {
    /// Optimiser iterations.
    pub iterations: usize,
    /// Largest move (metres) and turn (radians) of a keyframe.
    pub largest_change: (f64, f64),
    /// Time of the optimisation, ms.
    pub optimise_ms: f64,
    /// Loop edges kept in the graph.
    pub loops: usize,
}

/// What a search found.
#[derive(Debug, Default)]
pub(super) struct SearchOutcome {
    /// The frame of the keyframe it searched from.
    pub frame: usize,
    /// Every candidate verified, in order.
    pub loops: Vec<LoopRecord>,
    /// Refused optimisations (the poses kept).
    pub warnings: Vec<String>,
    /// The correction, when the optimisation moved a keyframe by more than
    /// [`LoopClosureConfig::min_move`].
    pub correction: Option<GraphCorrection>,
    /// The whole search's time, ms (on the thread).
    pub ms: f64,
    /// The CPU time its pool's workers spent on it, ms (`None` where the platform does not
    /// say): its cost, where `ms` includes the time it yielded to the front end.
    pub cpu_ms: Option<f64>,
}

impl GraphWork {
    /// Looks for loops of the newest keyframe, adds the accepted ones to the graph, and
    /// optimises it when one disagrees with the poses.
    pub fn search(&mut self, config: &LoopClosureConfig, frame: usize) -> SearchOutcome {
        let t = Instant::now();
        let mut outcome = SearchOutcome { frame, ..SearchOutcome::default() };
        for keyframe in std::mem::take(&mut self.new_keyframes) {
            self.detector.add(&keyframe);
        }
        if self.graph.poses().len() >= 2 {
            outcome.correction = self.search_and_optimise(config, frame, &mut outcome);
        }
        outcome.ms = t.elapsed().as_secs_f64() * 1e3;
        outcome
    }

    fn search_and_optimise(
        &mut self,
        config: &LoopClosureConfig,
        frame: usize,
        outcome: &mut SearchOutcome,
    ) -> Option<GraphCorrection> {
        let new = self.graph.poses().len() - 1;
        let verdicts: Vec<LoopVerdict> = self.detector.detect(new, self.graph.poses());
        let mut worth_optimising = false;
        let mut added = Vec::new();
        for v in verdicts {
            let mut record = LoopRecord {
                new_frame: v.frames.1,
                old_frame: v.frames.0,
                accepted: v.accepted(),
                rejection: v.rejection.map(|r| format!("{r:?}")),
                overlap: v.overlap,
                inlier_ratio: v.inlier_ratio,
                residual_m: v.residual_rms,
                correction_m: v.correction.0,
                correction_deg: v.correction.1.to_degrees(),
                feature_inliers: v.feature_inliers,
                chi2_before: None,
                edge: None,
            };
            if v.accepted() {
                let (st, sr) = config.loop_sigmas(v.residual_rms);
                let information = config
                    .loop_information_from_alignment
                    .then(|| alignment_information(&v.old_from_new, &v.hessian, st))
                    .flatten()
                    .unwrap_or_else(|| isotropic_information(st, sr));
                match self.graph.add_edge(PoseEdge {
                    from: v.old,
                    to: v.new,
                    from_from_to: v.old_from_new,
                    information,
                    kind: EdgeKind::Loop,
                }) {
                    Ok(e) => {
                        let chi2 = self.graph.edge_chi2(e);
                        worth_optimising |= chi2.is_some_and(|c| c > config.min_loop_chi2);
                        record.chi2_before = chi2;
                        record.edge = Some(e);
                        added.push(e);
                    }
                    Err(e) => {
                        record.accepted = false;
                        record.rejection = Some(format!("{e}"));
                    }
                }
            }
            outcome.loops.push(record);
        }
        if !worth_optimising {
            return None;
        }
        let before: Vec<DAffine3> = self.graph.poses().to_vec();
        let t = Instant::now();
        let result = self.graph.optimise(&config.graph);
        let optimise_ms = t.elapsed().as_secs_f64() * 1e3;
        let report = match result {
            Ok(r) => r,
            Err(e) => {
                // The poses are kept; the new loops must not poison later optimisations.
                for &edge in &added {
                    self.graph.reject(edge);
                }
                outcome.warnings.push(format!("loop closure at frame {frame}: {e}; poses kept"));
                return None;
            }
        };
        let report = if added.iter().any(|&e| self.graph.is_rejected(e)) {
            self.retry_with_looser_odometry(config).unwrap_or(report)
        } else {
            report
        };
        let moved = before.iter().zip(self.graph.poses()).any(|(a, b)| moved_by(a, b) > config.min_move);
        if !moved {
            return None;
        }
        let loops = self
            .graph
            .edges()
            .iter()
            .enumerate()
            .filter(|(i, e)| e.kind == EdgeKind::Loop && !self.graph.is_rejected(*i))
            .count();
        Some(GraphCorrection {
            iterations: report.iterations,
            largest_change: report.largest_change,
            optimise_ms,
            loops,
        })
    }

    /// When the optimiser refused loops: whether they agree with each other and with every
    /// accepted loop once the odometry is trusted less (its standard deviations 2, then 4
    /// times larger, up to [`MAX_ODOMETRY_SCALE`] times the configured ones). A tracker that
    /// drifts centimetres between keyframes makes true loops look like outliers against the
    /// configured millimetres; two or more loops (from different keyframe pairs) that all fit
    /// once the odometry is looser are evidence of that drift, not of wrong loops, while a
    /// lone loop stays refused. On success the graph keeps the looser odometry (for the edges
    /// to come too) and its optimised poses; otherwise nothing changes.
    fn retry_with_looser_odometry(&mut self, config: &LoopClosureConfig) -> Option<OptimisationReport> {
        let is_loop = |g: &PoseGraph, i: usize| g.edges()[i].kind == EdgeKind::Loop;
        let refused: Vec<usize> =
            (0..self.graph.edges().len()).filter(|&i| is_loop(&self.graph, i) && self.graph.is_rejected(i)).collect();
        if refused.len() < 2 {
            return None;
        }
        for k in [2.0, 4.0] {
            if self.odometry_scale * k > MAX_ODOMETRY_SCALE {
                break;
            }
            let mut g = self.graph.clone();
            g.scale_information(EdgeKind::Odometry, 1.0 / (k * k));
            for &e in &refused {
                g.restore(e);
            }
            let Ok(report) = g.optimise(&config.graph) else { continue };
            if (0..g.edges().len()).all(|i| !(is_loop(&g, i) && g.is_rejected(i))) {
                self.graph = g;
                self.odometry_scale *= k;
                return Some(report);
            }
        }
        None
    }
}

/// A search handed to the thread: the work and the keyframe's frame.
type Request = (Box<GraphWork>, usize);
/// What comes back: the work (the graph optimised, the database) and what was found.
type Response = (Box<GraphWork>, SearchOutcome);

/// The thread that runs searches, one at a time, and its channels.
pub(super) struct SearchThread {
    requests: Option<Sender<Request>>,
    responses: Receiver<Response>,
    handle: Option<JoinHandle<()>>,
}

impl SearchThread {
    /// Starts the thread with a pool of as many workers as the caller's.
    pub fn start(config: LoopClosureConfig) -> Result<Self> {
        let (request_tx, request_rx) = channel::<Request>();
        let (response_tx, response_rx) = channel::<Response>();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name(|i| format!("loop search worker {i}"))
            .start_handler(|_| crate::backend::lower_priority())
            .build()
            .map_err(|e| PipelineError::Backend(format!("loop closure: cannot start the worker pool: {e}")))?;
        let handle = std::thread::Builder::new()
            .name("loop search".into())
            .spawn(move || {
                crate::backend::lower_priority();
                // Each worker's CPU time, summed: the search runs on the pool's workers.
                let pool_cpu_ms = |pool: &rayon::ThreadPool| -> Option<f64> {
                    pool.broadcast(|_| crate::backend::thread_cpu_ms()).into_iter().sum()
                };
                for (mut work, frame) in request_rx {
                    let cpu_before = pool_cpu_ms(&pool);
                    let mut outcome = pool.install(|| work.search(&config, frame));
                    outcome.cpu_ms = pool_cpu_ms(&pool).zip(cpu_before).map(|(after, before)| after - before);
                    if response_tx.send((work, outcome)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| PipelineError::Backend(format!("loop closure: cannot start the search thread: {e}")))?;
        Ok(Self { requests: Some(request_tx), responses: response_rx, handle: Some(handle) })
    }

    /// Hands a search to the thread; false when the thread is gone.
    pub fn submit(&self, work: Box<GraphWork>, frame: usize) -> bool {
        self.requests.as_ref().is_some_and(|tx| tx.send((work, frame)).is_ok())
    }

    /// Waits for the search in hand; `None` when the thread died with it (a panic).
    pub fn wait(&self) -> Option<Response> {
        self.responses.recv().ok()
    }
}

impl Drop for SearchThread {
    fn drop(&mut self) {
        // Closing the request channel ends the thread's loop after the search in hand.
        self.requests.take();
        if let Some(handle) = self.handle.take() {
            // A panic on the thread was reported when its result did not come back.
            let _ = handle.join();
        }
    }
}
