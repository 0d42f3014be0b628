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
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    if threads < 2 || items.len() < serial_below.max(2) {
        return items.iter().map(f).collect();
    }
    let chunk = items.len().div_ceil(threads);
    let f = &f;
    // The first chunk on this thread, the others on threads of their own: one thread start
    // fewer than a thread a chunk, and this thread works instead of waiting (`hall-scan3d`'s
    // SLAM started some 37 threads a simulated second for its heading searches, each start a
    // stack mapped, cloned and unmapped).
    let mut parts = items.chunks(chunk);
    let first = parts.next().unwrap_or(&[]);
    std::thread::scope(|scope| {
        let rest: Vec<_> = parts
            .map(|part| scope.spawn(move || part.iter().map(f).collect::<Vec<R>>()))
            .collect();
        let mut out: Vec<R> = first.iter().map(f).collect();
        for h in rest {
            out.extend(h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)));
        }
        out
    })
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
}
