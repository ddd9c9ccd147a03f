#!/usr/bin/env bash
# Runs the cargo-fuzz targets (fuzz/fuzz_targets) for a bounded number of executions each.
#
#   scripts/fuzz.sh [RUNS] [TARGET ...]     default: 10000000 runs of every target
#
# Installs cargo-fuzz with `cargo install` when it is missing. cargo-fuzz needs a nightly
# compiler (-Zsanitizer); RUSTC_BOOTSTRAP=1 lets the stable toolchain stand in for one.
# Not run by CI: a campaign of 10⁷ executions per target takes hours on two cores.
# SANITIZER=none skips AddressSanitizer (faster; the targets are safe Rust, and panics
# are still caught).
set -euo pipefail
cd "$(dirname "$0")/../fuzz"

runs=${1:-10000000}
shift || true
if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi
export RUSTC_BOOTSTRAP=1
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo fuzz list)
fi
for target in "${targets[@]}"; do
    echo "== $target: $runs runs"
    log=$(mktemp)
    cargo fuzz run --sanitizer "${SANITIZER:-address}" "$target" -- \
        -runs="$runs" -max_len=4096 -print_final_stats=1 2>&1 | tee "$log" | grep -E "^(Done|stat::number_of_executed_units|==|thread|SUMMARY)" || true
    if grep -qE "^(SUMMARY|thread .* panicked)|deadly signal" "$log"; then
        echo "$target: FAILED (see fuzz/artifacts/$target)"; exit 1
    fi
    rm -f "$log"
done
