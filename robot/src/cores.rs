//! Work split over the machine's cores with its results in order, so that what the stack
//! computes is the same whatever the number of threads.

/// `f` of each of `items`, in their order, computed on the machine's cores in contiguous
/// chunks, a thread for each. Each result depends on its item alone, so the output is the
/// same whatever the number of threads; fewer than `serial_below` items stay on this thread,
/// where starting threads would cost more than it saves. Weighting the particles is most of
/// a particle filter's time (a ray cast and a likelihood for each beam of each particle; in
/// the depth camera's likelihood field, thousands of points for each), and scoring the
/// candidate headings most of a scan match's. (Rayon's pool, whose threads wait spinning for
/// work, doubled `hall-scan3d`'s SLAM time on two cores: its spinning took the cores from the
/// thread that had the work.)
pub fn map_on_cores<T: Sync, R: Send>(
    items: &[T],
    serial_below: usize,
    f: impl Fn(&T) -> R + Sync,
) -> Vec<R> {
    map_on_cores_with(items, serial_below, || (), |_, item| f(item))
}

/// [`map_on_cores`] with scratch state: each thread makes its own with `scratch` and hands it
/// to `f` with each of its items. The scratch may hold caches of work `f` would otherwise
/// repeat, but each result must still depend on its item alone (what a cache returns, `f`
/// would have computed), so that the output is the same whatever the number of threads.
pub fn map_on_cores_with<T: Sync, S, R: Send>(
    items: &[T],
    serial_below: usize,
    scratch: impl Fn() -> S + Sync,
    f: impl Fn(&mut S, &T) -> R + Sync,
) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let run = |part: &[T]| {
        let mut s = scratch();
        part.iter().map(|item| f(&mut s, item)).collect::<Vec<R>>()
    };
    if threads < 2 || items.len() < serial_below.max(2) {
        return run(items);
    }
    let chunk = items.len().div_ceil(threads);
    let run = &run;
    // The first chunk on this thread, the others on threads of their own: one thread start
    // fewer than a thread a chunk, and this thread works instead of waiting (`hall-scan3d`'s
    // SLAM started some 37 threads a simulated second for its heading searches, each start a
    // stack mapped, cloned and unmapped).
    let mut parts = items.chunks(chunk);
    let first = parts.next().unwrap_or(&[]);
    std::thread::scope(|scope| {
        let rest: Vec<_> = parts.map(|part| scope.spawn(move || run(part))).collect();
        let mut out: Vec<R> = run(first);
        for h in rest {
            out.extend(h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)));
        }
        out
    })
}

/// `f` of each of `items`, in their order, each item taken by whichever of the machine's
/// cores is free next. For a few items of uneven cost, where [`map_on_cores`]'s contiguous
/// chunks would leave one core the long ones and the other idle: the RGB-D map's five
/// registration methods took 2–11 s each, one after another, 34 s at the end of
/// `office-rgbd-methods`. Each result depends on its item alone and is put back in the
/// items' order, so the output is the same whatever the number of threads or which thread
/// took which item.
pub fn map_each_on_cores<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(items.len());
    if threads < 2 {
        return items.iter().map(f).collect();
    }
    let next = AtomicUsize::new(0);
    // Takes the next item not yet taken until none is left; each result with its index.
    let work = || {
        let mut done = Vec::new();
        loop {
            let k = next.fetch_add(1, Ordering::Relaxed);
            let Some(item) = items.get(k) else {
                return done;
            };
            done.push((k, f(item)));
        }
    };
    let work = &work;
    let mut done = std::thread::scope(|scope| {
        let rest: Vec<_> = (1..threads).map(|_| scope.spawn(work)).collect();
        let mut done = work();
        for h in rest {
            done.extend(h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)));
        }
        done
    });
    done.sort_unstable_by_key(|(k, _)| *k);
    done.into_iter().map(|(_, r)| r).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mapping on the cores gives every result in the items' order, for inputs below, at and
    /// well above the size that starts threads, with chunks that do not divide it evenly.
    #[test]
    fn mapping_on_the_cores_keeps_the_order() {
        for n in [0, 1, 256 - 1, 256, 1001, 5000] {
            let items: Vec<u64> = (0..n as u64).collect();
            let want: Vec<u64> = items.iter().map(|k| k * k + 1).collect();
            assert_eq!(map_on_cores(&items, 256, |k| k * k + 1), want, "{n} items");
            // Threads asked for whatever the count, even none or one item.
            assert_eq!(map_on_cores(&items, 0, |k| k * k + 1), want, "{n} items");
        }
    }

    /// With scratch state (here a cache of a function of each item's residue), the results
    /// are those computed without it, in order, and each thread makes its own scratch.
    #[test]
    fn mapping_with_scratch_keeps_the_results_and_the_order() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let slow = |r: u64| (0..=r).map(|i| i * i).sum::<u64>();
        for n in [0, 1, 255, 256, 1001, 5000] {
            let items: Vec<u64> = (0..n as u64).collect();
            let want: Vec<u64> = items.iter().map(|k| slow(k % 7) + k).collect();
            let made = AtomicUsize::new(0);
            let got = map_on_cores_with(
                &items,
                256,
                || {
                    made.fetch_add(1, Ordering::Relaxed);
                    [None::<u64>; 7]
                },
                |cache: &mut [Option<u64>; 7], k| {
                    *cache[(k % 7) as usize].get_or_insert_with(|| slow(k % 7)) + k
                },
            );
            assert_eq!(got, want, "{n} items");
            let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
            let made = made.load(Ordering::Relaxed);
            assert!(
                made >= 1 && made <= threads.max(1),
                "{made} scratches for {n} items"
            );
        }
    }
    /// Taking items as cores come free gives every result once, in the items' order,
    /// whatever the items' costs (here the first is the longest, so a free core takes
    /// several of the rest while it runs), for none, one and more items than cores.
    #[test]
    fn mapping_each_item_as_cores_come_free_keeps_the_order() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        for n in [0usize, 1, 2, 5, 40] {
            let items: Vec<u64> = (0..n as u64).collect();
            let calls = AtomicUsize::new(0);
            let got = map_each_on_cores(&items, |&k| {
                calls.fetch_add(1, Ordering::Relaxed);
                // Uneven work: item 0 costs as much as all the others together.
                let rounds = if k == 0 { 200_000 } else { 5_000 };
                (0..rounds).fold(k, |a, i| a.wrapping_mul(31).wrapping_add(i)) % 1000 + k * 1000
            });
            let want: Vec<u64> = items
                .iter()
                .map(|&k| {
                    let rounds = if k == 0 { 200_000 } else { 5_000 };
                    (0..rounds).fold(k, |a, i| a.wrapping_mul(31).wrapping_add(i)) % 1000 + k * 1000
                })
                .collect();
            assert_eq!(got, want, "{n} items");
            assert_eq!(calls.load(Ordering::Relaxed), n, "each item once");
        }
    }
}
