#!/usr/bin/env bash
# Render a cylaov dataset as a Slurm job array: one array task per shard.
#
#   cylaov generate --count 100000 --seed 1 --out /shared/data     # once, anywhere
#   sbatch --array=0-63 scripts/slurm-batch.sh /shared/data /shared/data/render
#
# Each task renders shard (SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN) of
# SLURM_ARRAY_TASK_COUNT; cylaov reads both from the environment. Use a contiguous
# --array range without a step (0-63, not 0-63:2); a throttle (%8) is fine.
# Re-submitting the same array resumes: finished views are verified and skipped.
# Failed views are listed in OUT/failures.K-of-N.jsonl and make the task exit non-zero.
#
# Extra cylaov options go after the two paths, e.g. --aov depth,normal,shape_id; with
# --format webdataset [--shard-size N] each task writes whole tar shards (tar j goes to task
# j % N) and the last to finish writes OUT/shards.json.
#
# Resources: one CPU and 1 GB per task by default, which any node can give (a request larger
# than every node, such as 8 CPUs on a 2-core node, leaves the array pending forever without
# a word). Ask for more on the command line and cylaov uses them:
#   sbatch --array=0-63 --cpus-per-task=4 --mem=2G scripts/slurm-batch.sh IN OUT
# scripts/slurm-test runs this script on a real one-node cluster.
#SBATCH --job-name=cylaov
#SBATCH --cpus-per-task=1
#SBATCH --mem=1G
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
