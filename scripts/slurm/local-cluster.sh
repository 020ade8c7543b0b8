#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for the test of the job-array scripts
# (host/tests/slurm.rs). Needs root and Debian's slurmctld, slurmd, slurm-client and munge.
#   local-cluster.sh start DIR PORT   state, logs and slurm.conf in DIR; slurmctld on PORT,
#                                     slurmd on PORT+1; waits until the node is idle
#   local-cluster.sh stop DIR         stops the daemons (and the cluster's own munged)
# Commands reach the cluster with SLURM_CONF=DIR/slurm.conf.
set -euo pipefail
what=${1:?start or stop} dir=${2:?folder}
conf=$dir/slurm.conf
case $what in
start)
  port=${3:?port}
  mkdir -p "$dir/state" "$dir/spool" "$dir/log"
  # munge authenticates the daemons and the clients to each other. The cluster has a munged of
  # its own (key, socket, pid and log in DIR/munge; slurm.conf's AuthInfo names the socket): a
  # system munged may be missing, stopped, or a stale socket left by one that was killed.
  m=$dir/munge
  mkdir -p "$m"
  chmod 700 "$m"
  dd if=/dev/urandom of="$m/munge.key" bs=1024 count=1 2>/dev/null
  chmod 400 "$m/munge.key"
  /usr/sbin/munged --force --socket="$m/socket" --key-file="$m/munge.key" \
    --pid-file="$m/munged.pid" --log-file="$m/munged.log" --seed-file="$m/munged.seed"
  for _ in $(seq 1 20); do
    if timeout 2 munge -n -S "$m/socket" 2>/dev/null | timeout 2 unmunge -S "$m/socket" >/dev/null 2>&1; then
      break
    fi
    sleep 0.5
  done
  if ! timeout 2 munge -n -S "$m/socket" 2>/dev/null | timeout 2 unmunge -S "$m/socket" >/dev/null 2>&1; then
    echo "munged did not answer on $m/socket in 10 s; its log:" >&2
    tail -n 20 "$m/munged.log" >&2 || true
    exit 1
  fi
  host=$(hostname -s)
  cat > "$conf" <<CONF
ClusterName=raytrace
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$m/socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
NodeName=$host NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
  /usr/sbin/slurmctld -f "$conf"
  /usr/sbin/slurmd -f "$conf"
  # Every query bounded (a client that cannot authenticate retries for most of a minute).
  deadline=$(($(date +%s) + 30))
  while [ "$(date +%s)" -lt "$deadline" ]; do
    if SLURM_CONF=$conf timeout 5 sinfo -h -o %t 2>/dev/null | grep -q idle; then
      exit 0
    fi
    sleep 0.5
  done
  echo "the Slurm node did not come up in 30 s; logs:" >&2
  tail -n 20 "$dir"/log/*.log >&2 || true
  exit 1
  ;;
stop)
  SLURM_CONF=$conf timeout 5 scontrol shutdown >/dev/null 2>&1 || true
  pids=""
  for f in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
    if [ -s "$f" ]; then pids="$pids $(cat "$f")"; fi
  done
  for pid in $pids; do kill "$pid" 2>/dev/null || true; done
  # Until they have exited (at most 10 s), so that their folder can go.
  for _ in $(seq 1 20); do
    alive=0
    for pid in $pids; do
      if kill -0 "$pid" 2>/dev/null && ! grep -q zombie "/proc/$pid/status" 2>/dev/null; then alive=1; fi
    done
    [ $alive = 0 ] && break
    sleep 0.5
  done
  ;;
*)
  echo "usage: local-cluster.sh start DIR PORT | stop DIR" >&2
  exit 2
  ;;
esac
