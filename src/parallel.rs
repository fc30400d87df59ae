//! Independent pieces of work on every core, their results in order.
//!
//! The analysis fits several models to one recording (the candidates of a
//! diagnosis, the three ellipsoids of a 3-D fit); each fit is a pure
//! function of the recording, so they can run at once and still give the
//! very same results in the very same order.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

/// `work` applied to each of `items`, the results in the order of `items`.
/// The items are shared out to as many threads as there are cores (at most
/// one per item), the calling thread being one of them; each thread takes
/// the next item when it is done, so at most one item's working memory
/// per thread is alive at once. A thread that cannot be started leaves its
/// share to the others; a panic in `work` is raised again here.
pub fn map_in_order<T, R, F>(items: &[T], work: F) -> Vec<R>
where
    T: Sync,
    R: Send,
    F: Fn(&T) -> R + Sync,
{
    let threads = cores().min(items.len());
    if threads <= 1 {
        return items.iter().map(&work).collect();
    }
    let next = AtomicUsize::new(0);
    let share = || {
        let mut done = Vec::new();
        loop {
            let index = next.fetch_add(1, Ordering::Relaxed);
            let Some(item) = items.get(index) else {
                break;
            };
            done.push((index, work(item)));
        }
        done
    };
    let mut results: Vec<Option<R>> = items.iter().map(|_| None).collect();
    std::thread::scope(|scope| {
        let helpers: Vec<_> = (1..threads)
            .filter_map(|_| std::thread::Builder::new().spawn_scoped(scope, share).ok())
            .collect();
        let mut place = |done: Vec<(usize, R)>| {
            for (index, result) in done {
                results[index] = Some(result);
            }
        };
        place(share());
        for helper in helpers {
            match helper.join() {
                Ok(done) => place(done),
                Err(panic) => std::panic::resume_unwind(panic),
            }
        }
    });
    // Every item was taken by a thread that was joined, so every result
    // is there; were one missing, it is worked out here rather than lost.
    results
        .into_iter()
        .zip(items)
        .map(|(result, item)| result.unwrap_or_else(|| work(item)))
        .collect()
}

/// The cores this process may use, asked once (the answer reads the
/// cgroup's files).
pub(crate) fn cores() -> usize {
    static CORES: OnceLock<usize> = OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_in_the_order_of_the_items_whatever_the_threads_do() {
        let items: Vec<u64> = (0..200).collect();
        // Uneven work, so the threads finish out of order.
        let got = map_in_order(&items, |&k| {
            let mut x = k;
            for _ in 0..(k % 7) * 10_000 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
            (k, x)
        });
        let want: Vec<(u64, u64)> = items
            .iter()
            .map(|&k| {
                let mut x = k;
                for _ in 0..(k % 7) * 10_000 {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                }
                (k, x)
            })
            .collect();
        assert_eq!(got, want);
    }

    #[test]
    fn no_items_and_one_item() {
        assert!(map_in_order(&[] as &[u8], |&k| k).is_empty());
        assert_eq!(map_in_order(&[3u8], |&k| k * 2), vec![6]);
    }

    #[test]
    #[should_panic(expected = "item 5")]
    fn a_panic_in_the_work_is_raised_again() {
        let items: Vec<u32> = (0..10).collect();
        map_in_order(&items, |&k| {
            assert!(k != 5, "item 5");
            k
        });
    }
}
