//! Work spread over threads: the suite's scenarios, a tuning round's trials, the folds' and a
//! twin ranking's SLAM runs. Results come back in the items' order, so that how many threads
//! ran changes the wall time only, never an output.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// `f` of every item on `jobs` threads, the results in the items' order whatever order the
/// threads finish in.
///
/// With two threads or more, each is held to its own share of the cores this thread may run
/// on ([`core_shares`]; Linux only), and so is all a run does on it: the threads it starts and
/// the processes it spawns (a suite's `--isolate` runs) inherit the share. A run on two cores
/// splits its heavier steps over both (`futago_robot::cores`, Mesa llvmpipe's rasteriser
/// threads), and two such runs side by side on two cores waited on each other's threads:
/// held to a core each, they split nothing (Mesa sizes llvmpipe's pool by the affinity of the
/// thread that starts its first renderer in a process, so an `--isolate` run's starts no
/// threads), and the shipped suite took 526.9 s instead of
/// 631.7 s (its runs 1,005 s summed instead of 1,205 s; stop 94, `futago suite scenarios/
/// --jobs 2 --isolate`, in the same hour). What a run computes does not depend on its
/// threads, so the outputs stay the same.
pub fn parallel_map<T: Sync, R: Send>(
    items: &[T],
    jobs: usize,
    f: impl Fn(usize, &T) -> R + Sync,
) -> Vec<R> {
    let workers = jobs.max(1).min(items.len());
    let shares = core_shares(&allowed_cores(), workers);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for w in 0..workers {
            let share = shares.get(w);
            let (next, results, f) = (&next, &results, &f);
            scope.spawn(move || {
                if let Some(cores) = share {
                    // Only the wall time depends on it: a thread that cannot be held runs
                    // where the system puts it.
                    let _ = hold_to(cores);
                }
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(item) = items.get(i) else {
                        break;
                    };
                    let r = f(i, item);
                    results.lock().expect("no worker panicked")[i] = Some(r);
                }
            });
        }
    });
    results
        .into_inner()
        .expect("no worker panicked")
        .into_iter()
        .map(|r| r.expect("every item was mapped"))
        .collect()
}

/// The cores each of `workers` threads is held to: `cores` split, in their order, into
/// `min(workers, cores)` runs of consecutive entries whose lengths differ by one at most,
/// thread k on run k modulo their number (more threads than cores share them). None for
/// fewer than two threads or no known cores: one thread keeps every core.
pub fn core_shares(cores: &[usize], workers: usize) -> Vec<Vec<usize>> {
    let n = cores.len();
    if workers < 2 || n == 0 {
        return Vec::new();
    }
    let groups = workers.min(n);
    (0..workers)
        .map(|k| {
            let g = k % groups;
            cores[g * n / groups..(g + 1) * n / groups].to_vec()
        })
        .collect()
}

/// The cores the calling thread may run on, in increasing order (empty where unknown).
pub fn allowed_cores() -> Vec<usize> {
    #[cfg(target_os = "linux")]
    {
        use rustix::thread::{CpuSet, sched_getaffinity};
        match sched_getaffinity(None) {
            Ok(set) => (0..CpuSet::MAX_CPU).filter(|&c| set.is_set(c)).collect(),
            Err(_) => Vec::new(),
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        Vec::new()
    }
}

/// Holds the calling thread (and the threads and processes it starts after) to `cores`.
pub fn hold_to(cores: &[usize]) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use rustix::thread::{CpuSet, sched_setaffinity};
        let mut set = CpuSet::new();
        for &c in cores.iter().filter(|&&c| c < CpuSet::MAX_CPU) {
            set.set(c);
        }
        sched_setaffinity(None, &set).map_err(std::io::Error::from)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = cores;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two threads on two cores get one each; on eight, four each in order; three threads on
    /// eight cores get 2, 3 and 3 (⌊8k/3⌋ bounds); more threads than cores take them in turn;
    /// one thread, or no known core, holds nothing.
    #[test]
    fn threads_share_the_cores_in_even_runs() {
        assert_eq!(core_shares(&[0, 1], 2), vec![vec![0], vec![1]]);
        assert_eq!(
            core_shares(&[0, 1, 2, 3, 4, 5, 6, 7], 2),
            vec![vec![0, 1, 2, 3], vec![4, 5, 6, 7]]
        );
        assert_eq!(
            core_shares(&[0, 1, 2, 3, 4, 5, 6, 7], 3),
            vec![vec![0, 1], vec![2, 3, 4], vec![5, 6, 7]]
        );
        assert_eq!(
            core_shares(&[2, 5], 3),
            vec![vec![2], vec![5], vec![2]],
            "three threads on two cores"
        );
        assert!(core_shares(&[0, 1, 2, 3], 1).is_empty());
        assert!(core_shares(&[], 4).is_empty());
    }

    /// On Linux a thread held to one of its cores sees that core alone (so the work it splits
    /// over the cores stays on it), and the mapped results come back in order all the same.
    #[test]
    fn a_held_thread_sees_only_its_share() {
        let cores = allowed_cores();
        if !cfg!(target_os = "linux") || cores.len() < 2 {
            return;
        }
        let seen = std::thread::scope(|s| {
            s.spawn(|| {
                hold_to(&cores[1..2]).unwrap();
                (
                    allowed_cores(),
                    std::thread::available_parallelism().unwrap().get(),
                )
            })
            .join()
            .unwrap()
        });
        assert_eq!(seen, (vec![cores[1]], 1));
        // This thread keeps its cores.
        assert_eq!(allowed_cores(), cores);
        let items: Vec<u64> = (0..50).collect();
        let out = parallel_map(&items, 2, |i, &k| (i as u64, k * k));
        assert_eq!(out, items.iter().map(|&k| (k, k * k)).collect::<Vec<_>>());
    }
}
