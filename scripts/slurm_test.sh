#!/usr/bin/env bash
# A sweep through a real Slurm: installs Debian's slurm-wlm and munge (apt-get), starts a
# single-node cluster on this machine, emits a two-point sweep with `hemodpd sweep --emit-slurm`,
# submits it with sbatch, waits for it, gathers the table with `hemodpd sweep-collect`, runs the
# same grid locally (on the core the one-CPU tasks leave free, while they run) and checks that
# the two tables agree point by point (every result identical; wall times excluded). Then a capillary point that cannot meet its one-minute limit: Slurm's
# early SIGTERM (#SBATCH --signal) makes it checkpoint and stop, sweep-collect lists it, its
# resubmit command resumes it to the end, and its results equal an uninterrupted local run's.
# Exits non-zero on any failure. CI runs it after the test suite.
#
# Needs root (or sudo) on Debian/Ubuntu. Nothing in /etc/slurm is touched: slurm.conf, the spool,
# state and log directories live in a temporary directory (SLURM_CONF points there) and the
# daemons listen on ports 16817/16818. munge uses the system's key and /run/munge (created if
# missing); a munged that already answers is used as it is. The daemons this script starts are
# stopped by their process ids when it ends. The binary is target/debug/hemodpd (built with the
# test profile, as `cargo test` does) unless HEMODPD names another.
#
# Environment: HEMODPD (binary), SLURM_TEST_TIMEOUT (seconds to wait for a job; default 120; the
# capillary jobs get 300 s more),
# SLURM_TEST_KEEP=1 keeps the temporary directory.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
TIMEOUT=${SLURM_TEST_TIMEOUT:-120}
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
t_start=$(date +%s)
say() { echo "slurm_test [$(( $(date +%s) - t_start )) s]: $*" >&2; }
fail() { say "FAIL: $*"; exit 1; }

# 1. packages
need=()
for p in slurm-wlm munge python3; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  say "installing ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

# 2. the binary
if [ -z "${HEMODPD:-}" ]; then
  # the whole workspace's feature set (--workspace), which is the test build's (Cargo.toml), so
  # after `cargo nextest run` nothing compiles here
  say "building hemodpd (test profile)"
  cargo build -q --profile test --workspace --bins
  HEMODPD="$ROOT/target/debug/hemodpd"
fi
[ -x "$HEMODPD" ] || fail "no hemodpd binary at $HEMODPD"

WORK=$(mktemp -d /tmp/hemodpd-slurm.XXXXXX)
chmod 755 "$WORK"
started_pids=()
local_pids=()
cleanup() {
  local rc=$?
  for pid in "${local_pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  for pid in "${started_pids[@]}"; do
    $SUDO kill "$pid" 2>/dev/null || true
  done
  for pid in "${started_pids[@]}"; do
    for _ in $(seq 50); do $SUDO kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
  done
  if [ "$rc" -ne 0 ]; then
    for f in "$WORK"/log/*.log; do [ -f "$f" ] && { say "--- $f (last lines)"; tail -n 20 "$f" >&2; }; done
  fi
  if [ "${SLURM_TEST_KEEP:-0}" = 1 ]; then say "kept $WORK"; else $SUDO rm -rf "$WORK"; fi
  exit "$rc"
}
trap cleanup EXIT

# 3. munge: the system key and runtime directory; start munged unless one already answers
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  if [ ! -s /etc/munge/munge.key ]; then
    say "creating /etc/munge/munge.key"
    $SUDO install -d -o munge -g munge -m 700 /etc/munge
    $SUDO dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
  fi
  $SUDO chown munge:munge /etc/munge/munge.key
  $SUDO chmod 400 /etc/munge/munge.key
  for d in /run/munge /var/lib/munge /var/log/munge; do
    $SUDO install -d -o munge -g munge -m 755 "$d"
  done
  $SUDO chmod 700 /var/lib/munge /var/log/munge
  say "starting munged"
  $SUDO runuser -u munge -- /usr/sbin/munged
  for _ in $(seq 50); do [ -s /run/munge/munged.pid ] && break; sleep 0.1; done
  [ -s /run/munge/munged.pid ] || fail "munged did not start (no /run/munge/munged.pid)"
  started_pids+=("$($SUDO cat /run/munge/munged.pid)")
  for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
fi
munge -n | unmunge >/dev/null || fail "munge -n | unmunge does not work"

# 4. a single-node Slurm configured in $WORK
NODE=$(hostname -s)
CPUS=$(nproc)
MEM_MB=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.8 }' /proc/meminfo)
mkdir -p "$WORK/spool/ctld" "$WORK/spool/d" "$WORK/log" "$WORK/run"
export SLURM_CONF="$WORK/slurm.conf"
cat >"$SLURM_CONF" <<EOF
# single-node test cluster of scripts/slurm_test.sh (temporary)
ClusterName=hemodpdtest
SlurmctldHost=$NODE(127.0.0.1)
SlurmctldPort=16817
SlurmdPort=16818
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CryptoType=crypto/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
SchedulerType=sched/backfill
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
StateSaveLocation=$WORK/spool/ctld
SlurmdSpoolDir=$WORK/spool/d
SlurmctldPidFile=$WORK/run/slurmctld.pid
SlurmdPidFile=$WORK/run/slurmd.pid
SlurmctldLogFile=$WORK/log/slurmctld.log
SlurmdLogFile=$WORK/log/slurmd.log
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=300
KillWait=10
Waittime=0
NodeName=$NODE NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$MEM_MB State=UNKNOWN
PartitionName=debug Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
say "starting slurmctld and slurmd ($NODE, $CPUS CPUs, $MEM_MB MB)"
$SUDO env SLURM_CONF="$SLURM_CONF" /usr/sbin/slurmctld -D -c >"$WORK/log/slurmctld.out" 2>&1 &
started_pids+=("$!")
for _ in $(seq 100); do scontrol ping 2>/dev/null | grep -q UP && break; sleep 0.2; done
scontrol ping | grep -q UP || fail "slurmctld did not come up"
$SUDO env SLURM_CONF="$SLURM_CONF" /usr/sbin/slurmd -D >"$WORK/log/slurmd.out" 2>&1 &
started_pids+=("$!")
state=""
for _ in $(seq 150); do
  state=$(sinfo -h -N -n "$NODE" -o %T 2>/dev/null | head -n1)
  [ "$state" = idle ] && break
  sleep 0.2
done
[ "$state" = idle ] || fail "node $NODE is '$state', not idle, after 30 s"
say "cluster up: $(sinfo -h -o '%P %D %T %C')"

# 5. the sweep: two points of the stretching scenario with tiny settings
SCEN="$ROOT/scenarios/stretching.toml"
GRID=(--vary membrane.vertices=100,162 --set "stretching.forces_pn=[0.0, 50.0, 100.0]")
SW="$WORK/slurm-sweep"
"$HEMODPD" sweep "$SCEN" "${GRID[@]}" --emit-slurm "$SW" --slurm-time 00:05:00 --slurm-mem 200M \
  --slurm-cpus 1 --slurm-partition debug
[ -f "$SW/sweep.sbatch" ] || fail "no $SW/sweep.sbatch"
grep -q '^#SBATCH --array=0-1$' "$SW/sweep.sbatch" || fail "the script's array is not 0-1"
# before the job: collect lists both points and the resubmit command, exit status 2
set +e
"$HEMODPD" sweep-collect "$SW" >/dev/null 2>"$WORK/collect0.err"
rc=$?
set -e
[ "$rc" -eq 2 ] || fail "sweep-collect before the job exited with $rc, expected 2"
grep -q -- "--array=0,1" "$WORK/collect0.err" || fail "sweep-collect did not print the resubmit command: $(cat "$WORK/collect0.err")"

JOB=$(sbatch --parsable "$SW/sweep.sbatch")
JOB=${JOB%%;*}
say "submitted job array $JOB"
# the same grid locally, on the core the one-CPU tasks leave free (compared in step 6)
LOCAL="$WORK/local-sweep"
"$HEMODPD" sweep "$SCEN" "${GRID[@]}" --out "$LOCAL" --jobs 1 --threads-per-job 1 --quiet >/dev/null 2>"$WORK/local-sweep.err" &
LOCAL_PID=$!
local_pids+=("$LOCAL_PID")
t0=$(date +%s)
while [ -n "$(squeue -h -j "$JOB" 2>/dev/null)" ]; do
  [ $(( $(date +%s) - t0 )) -lt "$TIMEOUT" ] || { squeue -j "$JOB" >&2; fail "job $JOB still queued or running after $TIMEOUT s"; }
  sleep 1
done
say "job $JOB left the queue after $(( $(date +%s) - t0 )) s"
ls "$SW"/slurm/*.out >/dev/null 2>&1 || fail "no Slurm task output in $SW/slurm"
"$HEMODPD" sweep-collect "$SW" || { cat "$SW"/slurm/*.out >&2; fail "sweep-collect: the job array did not finish every point"; }

# a resubmitted task on a finished point skips it
JOB2=$(sbatch --parsable --array=1 "$SW/sweep.sbatch")
JOB2=${JOB2%%;*}
t0=$(date +%s)
while [ -n "$(squeue -h -j "$JOB2" 2>/dev/null)" ]; do
  [ $(( $(date +%s) - t0 )) -lt "$TIMEOUT" ] || fail "job $JOB2 still queued after $TIMEOUT s"
  sleep 1
done
grep -q "has finished" "$SW/slurm/${JOB2}_1.out" || fail "the resubmitted task did not skip its finished point: $(cat "$SW/slurm/${JOB2}_1.out")"

# 6. the comparison with the local run of the same grid
wait "$LOCAL_PID" || fail "the local sweep failed: $(cat "$WORK/local-sweep.err")"
python3 - "$SW/sweep.json" "$LOCAL/sweep.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
timing = set(a["timing_columns"])
assert a["columns"] == b["columns"], (a["columns"], b["columns"])
assert len(a["runs"]) == len(b["runs"]) == 2, (len(a["runs"]), len(b["runs"]))
for ra, rb in zip(a["runs"], b["runs"]):
    for k in ("index", "label", "values", "overrides", "status"):
        assert ra[k] == rb[k], (k, ra[k], rb[k])
    assert ra["status"] == "done", ra
    for c in a["columns"]:
        if c in timing:
            continue
        assert ra["metrics"][c] is not None, (c, ra)
        assert ra["metrics"][c] == rb["metrics"][c], (ra["label"], c, ra["metrics"][c], rb["metrics"][c])
    shown = ", ".join("%s = %r" % (c, ra["metrics"][c]) for c in a["columns"] if c not in timing)
    print("  %s: identical (%s)" % (ra["label"], shown))
PY
say "the Slurm sweep's table equals the local one point by point"

wait_job() { # JOB SECONDS
  local t0; t0=$(date +%s)
  while [ -n "$(squeue -h -j "$1" 2>/dev/null)" ]; do
    [ $(( $(date +%s) - t0 )) -lt "$2" ] || { squeue -j "$1" >&2; fail "job $1 still queued or running after $2 s"; }
    sleep 1
  done
}

# 7. a point that meets its time limit: a capillary point of about 85 s on one CPU, given one minute
CAP="$ROOT/scenarios/capillary.toml"
CGRID=(--vary seed=1 --set cell.parameters=paper --set stage.1.duration_s=0.02 --set stage.2.duration_s=0.01)
CW="$WORK/slurm-capillary"
"$HEMODPD" sweep "$CAP" "${CGRID[@]}" --emit-slurm "$CW" --slurm-time 1 --slurm-cpus 1 --slurm-partition debug
grep -q '^#SBATCH --signal=B:TERM@30$' "$CW/sweep.sbatch" || fail "no --signal line for a 1-minute limit: $(grep SBATCH "$CW/sweep.sbatch")"
JOB3=$(sbatch --parsable "$CW/sweep.sbatch")
JOB3=${JOB3%%;*}
say "submitted capillary job $JOB3 with a 1-minute limit"
# the uninterrupted reference run, on the other core while the task and its resubmission run
CLOCAL="$WORK/local-capillary"
"$HEMODPD" sweep "$CAP" "${CGRID[@]}" --out "$CLOCAL" --jobs 1 --threads-per-job 1 --quiet >/dev/null 2>"$WORK/local-capillary.err" &
CLOCAL_PID=$!
local_pids+=("$CLOCAL_PID")
local_pids+=("$LOCAL_PID")
wait_job "$JOB3" $(( TIMEOUT + 300 ))
OUT3="$CW/slurm/${JOB3}_0.out"
grep -q "interrupted at step" "$OUT3" || fail "the capillary task was not stopped by its signal with a checkpoint: $(tail -n 5 "$OUT3")"
CK=$(find "$CW" -name checkpoint.h5 | head -n1)
[ -n "$CK" ] || fail "no checkpoint.h5 in $CW after the time limit"
PDIR=$(dirname "$CK")
python3 -c 'import json,sys; s=json.load(open(sys.argv[1])); assert s["state"]=="interrupted", s' "$PDIR/sweep-status.json" \
  || fail "sweep-status.json of the stopped point: $(cat "$PDIR/sweep-status.json")"
[ ! -e "$PDIR/summary.json" ] || fail "the stopped point wrote summary.json"
set +e
"$HEMODPD" sweep-collect "$CW" >/dev/null 2>"$WORK/collect3.err"
rc=$?
set -e
[ "$rc" -eq 2 ] || fail "sweep-collect after the time limit exited with $rc, expected 2"
grep -q -- "--array=0" "$WORK/collect3.err" || fail "sweep-collect did not list the stopped point: $(cat "$WORK/collect3.err")"
say "the point checkpointed at its limit ($(grep -o 'interrupted at step [0-9]*' "$OUT3")); resubmitting it"
JOB4=$(sbatch --parsable --array=0 --time=10 "$CW/sweep.sbatch")
JOB4=${JOB4%%;*}
wait_job "$JOB4" $(( TIMEOUT + 300 ))
grep -q "resuming from its checkpoint" "$CW/slurm/${JOB4}_0.out" || fail "the resubmitted task did not resume: $(tail -n 5 "$CW/slurm/${JOB4}_0.out")"
"$HEMODPD" sweep-collect "$CW" >/dev/null || { cat "$CW"/slurm/*.out >&2; fail "the resumed capillary point did not finish"; }
wait "$CLOCAL_PID" || fail "the uninterrupted local capillary run failed: $(cat "$WORK/local-capillary.err")"
python3 - "$CW/sweep.json" "$CLOCAL/sweep.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
timing = set(a["timing_columns"])
ra, rb = a["runs"][0], b["runs"][0]
assert ra["status"] == rb["status"] == "done", (ra, rb)
checked = 0
for c in a["columns"]:
    if c in timing or ra["metrics"][c] is None:
        continue
    assert ra["metrics"][c] == rb["metrics"][c], (c, ra["metrics"][c], rb["metrics"][c])
    checked += 1
assert checked >= 3, a["columns"]
print("  capillary point stopped at its limit and resumed: %d results identical to the uninterrupted run" % checked)
PY
say "PASS: the Slurm sweep's table equals the local one point by point; a point past its time limit checkpoints and resumes to the same results ($(( $(date +%s) - t_start )) s)"
