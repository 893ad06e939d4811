#!/usr/bin/env bash
# perch2 estimate loses nothing (issue 20): on a generated 3-image dataset, against one clean run,
#   - a truncated depth PNG in the middle, a truncated rgb PNG (3dof) or a missing mask (6dof), a malformed
#     scene_gt.json (6dof) or scene_camera.json (3dof, which never reads the ground truth: a broken
#     scene_gt.json costs nothing) entry: only that image is missing, the other rows are the clean run's,
#     exit status 3, the summary names the file and the reason; --strict stops at the first (exit 1); an unwritable output or
#     no models_info.json fails at once (exit 1);
#   - a second run on the same output while one runs fails (exit 1); a run killed (SIGKILL) after its first
#     image, with a torn line appended, then --resume: the torn line is reported and dropped and the rows are
#     the clean run's;
#   - SIGINT / SIGTERM during a run: exit 130 / 143 with a message, a CSV of finished images, --resume
#     completes it.
# Rows are compared on every column but time.
# Usage: cli_runs.sh PERCH2 3dof|6dof WORK_DIR [SIGNALS ("INT TERM")] [OBJECTS per image (2)]
set -euo pipefail
perch2=$1 mode=$2 work=$3 signals=${4:-"INT TERM"} objects=${5:-2}
rm -rf "$work"
mkdir -p "$work"
cd "$work"

fail() {
  echo "FAIL ($mode): $*" >&2
  exit 1
}
rows() { grep -v '^scene_id' "$1" | cut -d, -f1-6 | sort; }  # every column but time
rows_but_image() { rows "$1" | awk -F, -v im="$2" '$2 != im'; }
images_in() { grep -v '^scene_id' "$1" | cut -d, -f1,2 | sort -u | wc -l; }
est() { "$perch2" estimate --mode "$mode" --backend cpu "$@"; }
# est ... with its exit status in $rc and its output in $log (no set -e abort).
run() {
  local log_file=$1
  shift
  set +e
  est "$@" >"$log_file" 2>&1
  rc=$?
  set -e
  log=$(cat "$log_file")
}
expect() {  # expect RC FILE_PATTERN...: exit status and messages of the last run
  [ "$rc" -eq "$1" ] || fail "exit status $rc, expected $1:"$'\n'"$log"
  shift
  for p in "$@"; do grep -q -- "$p" <<<"$log" || fail "no '$p' in the output:"$'\n'"$log"; done
}
# Waits until FILE.done records N images of the run PID; fails if the run ends first.
wait_done() {
  local pid=$1 file=$2 n=$3
  for _ in $(seq 1 3000); do
    [ -s "$file.done" ] && [ "$(grep -vc '^scene_id' "$file.done")" -ge "$n" ] && return
    kill -0 "$pid" 2>/dev/null || fail "the run ended before its image $n was done"
    sleep 0.02
  done
  fail "no image done within 60 s"
}
kill_after() {  # kill_after PID FILE N SIGNAL
  wait_done "$1" "$2" "$3"
  kill -"$4" "$1"
}

"$perch2" generate --mode "$mode" --scenes 1 --images-per-scene 3 --objects "$objects" --seed 5 --out data >/dev/null
run clean.log --dataset data --out clean.csv
expect 0
[ "$(images_in clean.csv)" -eq 3 ] || fail "the clean run has rows of $(images_in clean.csv) images, not 3"
scene=data/test/000001

# Bad images: each costs only itself.
cp -r data bad_depth
head -c 3000 $scene/depth/000001.png >bad_depth/test/000001/depth/000001.png
run bad_depth.log --dataset bad_depth --out bad_depth.csv
expect 3 "skipped scene 1 image 1" "depth/000001.png: truncated PNG" "1 image(s) skipped"
[ "$(rows bad_depth.csv)" == "$(rows_but_image clean.csv 1)" ] || fail "truncated depth: other rows differ"
run strict.log --dataset bad_depth --out strict.csv --strict
expect 1 "stopped at the first (--strict)"
[ "$(rows strict.csv)" == "$(rows clean.csv | awk -F, '$2 == 0')" ] || fail "--strict: not image 0's rows only"

cp -r data bad_file
if [ "$mode" = 6dof ]; then
  rm bad_file/test/000001/mask_visib/000002_000000.png
  what="mask_visib/000002_000000.png: file not found"
else
  head -c 5000 $scene/rgb/000002.png >bad_file/test/000001/rgb/000002.png
  what="rgb/000002.png: truncated PNG"
fi
run bad_file.log --dataset bad_file --out bad_file.csv
expect 3 "skipped scene 1 image 2" "$what"
[ "$(rows bad_file.csv)" == "$(rows_but_image clean.csv 2)" ] || fail "$what: other rows differ"

# A malformed entry of a scene file the run reads: scene_gt.json for 6-DoF with ground-truth masks, else
# scene_camera.json (the ground truth is never read then: a broken scene_gt.json costs nothing).
cp -r data bad_json
if [ "$mode" = 6dof ]; then
  sed -i '/^  "0": /s/cam_t_m2c/cam_t_broken/' bad_json/test/000001/scene_gt.json
  what="scene_gt.json: image 0 instance 0: missing key \"cam_t_m2c\""
else
  sed -i '/^  "0": /s/cam_K/cam_K_broken/' bad_json/test/000001/scene_camera.json
  what="scene_camera.json: image 0: missing key \"cam_K\""
  cp -r data bad_gt
  sed -i '/^  "0": /s/cam_t_m2c/cam_t_broken/' bad_gt/test/000001/scene_gt.json
  rm bad_gt/test/000001/scene_gt_info.json
  run bad_gt.log --dataset bad_gt --out bad_gt.csv
  expect 0
  [ "$(rows bad_gt.csv)" == "$(rows clean.csv)" ] || fail "3-DoF read the ground truth: rows differ"
fi
run bad_json.log --dataset bad_json --out bad_json.csv
expect 3 "skipped scene 1 image 0" "$what"
[ "$(rows bad_json.csv)" == "$(rows_but_image clean.csv 0)" ] || fail "malformed scene entry: other rows differ"

# Dataset-level problems still fail at once, before any image.
run unwritable.log --dataset data --out no_such_dir/r.csv
expect 1 "no_such_dir/r.csv: cannot be written"
cp -r data no_info
rm no_info/models/models_info.json
run no_info.log --dataset no_info --out no_info.csv
expect 1 "models_info.json"

# Killed after its first image (plus a torn line, as a kill during a write would leave), then resumed.
"$perch2" estimate --mode "$mode" --backend cpu --dataset data --out killed.csv >killed.log 2>&1 &
pid=$!
wait_done $pid killed.csv 1
run second.log --dataset data --out killed.csv --resume  # a second writer of the same file while it runs
expect 1 "killed.csv: is being written by another process"
kill -KILL $pid
wait $pid || true
[ "$(images_in killed.csv)" -lt 3 ] || fail "SIGKILL: the run was not stopped in the middle"
comm -23 <(rows killed.csv) <(rows clean.csv) | grep -q . && fail "SIGKILL: rows not in the clean run"
printf '1,2,7,0.5,1 0 0 0 1' >>killed.csv
run resume.log --dataset data --out killed.csv --resume
expect 0 "killed.csv:[0-9]*: dropped: torn last line" "complete images"
[ "$(rows killed.csv)" == "$(rows clean.csv)" ] || fail "killed + --resume: rows differ from the clean run"

for sig in $signals; do
  "$perch2" estimate --mode "$mode" --backend cpu --dataset data --out "$sig.csv" >"$sig.log" 2>&1 &
  pid=$!
  kill_after $pid "$sig.csv" 1 "$sig"
  set +e
  wait $pid
  rc=$?
  set -e
  log=$(cat "$sig.log")
  want=143
  [ "$sig" = INT ] && want=130
  expect $want "interrupted by SIG$sig" "run again with --resume"
  [ "$(images_in "$sig.csv")" -lt 3 ] || fail "SIG$sig: the run did not stop early"
  [ "$(tail -c 1 "$sig.csv")" == "" ] || fail "SIG$sig: the CSV does not end with a newline"
  comm -23 <(rows "$sig.csv") <(rows clean.csv) | grep -q . && fail "SIG$sig: rows not in the clean run"
  run "$sig.resume.log" --dataset data --out "$sig.csv" --resume
  expect 0
  [ "$(rows "$sig.csv")" == "$(rows clean.csv)" ] || fail "SIG$sig + --resume: rows differ from the clean run"
done
echo "cli_runs $mode: all checks passed"
