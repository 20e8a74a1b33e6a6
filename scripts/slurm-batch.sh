#!/usr/bin/env bash
# Render a cylaov dataset as a Slurm job array: one array task per shard.
#
#   cylaov generate --count 100000 --seed 1 --out /shared/data     # once, anywhere
#   sbatch --array=0-63 scripts/slurm-batch.sh /shared/data /shared/data/render
#   sbatch --array=0-63 --cpus-per-task=8 scripts/slurm-batch.sh IN OUT  # 8 threads a task
#
# Each task asks for one CPU unless --cpus-per-task is given on the sbatch command line;
# cylaov runs that many threads (SLURM_CPUS_PER_TASK). No CPU count is fixed here: a task
# asking for more CPUs than a node has stays pending forever, and Slurm does not say why.
# Memory: 2G covers a 1080p all-AOV view with room; ask for more with --mem for larger
# images (the batch bounds how many views are in flight to the memory it is given).
#
# Each task renders shard (SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN) of
# SLURM_ARRAY_TASK_COUNT; cylaov reads both from the environment. Use a contiguous
# --array range without a step (0-63, not 0-63:2); a throttle (%8) is fine.
# Re-submitting the same array resumes: finished views are verified and skipped.
# Failed views are listed in OUT/failures.K-of-N.jsonl and make the task exit non-zero.
#
# Extra cylaov options go after the two paths, e.g. --aov depth,normal,shape_id.
#SBATCH --job-name=cylaov
#SBATCH --mem=2G
#SBATCH --time=04:00:00
#SBATCH --output=cylaov-%A_%a.log
set -euo pipefail

input=${1:?usage: sbatch --array=0-N scripts/slurm-batch.sh INPUT OUT [cylaov options]}
out=${2:?usage: sbatch --array=0-N scripts/slurm-batch.sh INPUT OUT [cylaov options]}
shift 2
# The binary: $CYLAOV, else cylaov on PATH. (For a container: CYLAOV="apptainer exec
# cylaov.sif cylaov".)
cylaov=${CYLAOV:-cylaov}

exec $cylaov batch "$input" --out "$out" --threads "${SLURM_CPUS_PER_TASK:-1}" "$@"
