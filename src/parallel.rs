//! Work spread over the machine's cores (std threads, scoped): the vehicle computer has
//! a few cores and a calibration's independent pieces (a survey's visits, a rig's pair
//! runs) need not wait for each other.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// `f(index, item)` for every item, on up to every core; the results in the items' order.
/// A panic in `f` is a panic of the caller.
pub fn map<T: Sync, R: Send>(items: &[T], f: impl Fn(usize, &T) -> R + Sync) -> Vec<R> {
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get()).min(items.len());
    if workers <= 1 {
        return items.iter().enumerate().map(|(i, item)| f(i, item)).collect();
    }
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<R>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(item) = items.get(i) else { break };
                let outcome = f(i, item);
                slots.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(outcome);
            });
        }
    });
    let slots = slots.into_inner().unwrap_or_else(|e| e.into_inner());
    // Every index below len was taken by a worker, and a worker's panic ended the scope
    // with a panic above: every slot is filled here.
    slots.into_iter().map(|r| r.expect("every item mapped")).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn results_come_in_the_items_order() {
        let items: Vec<u64> = (0..37).collect();
        let squares = super::map(&items, |i, v| (i as u64) * v);
        assert_eq!(squares, items.iter().map(|v| v * v).collect::<Vec<_>>());
        assert!(super::map(&[] as &[u8], |_, v| *v).is_empty());
    }
}
