# Shared by the example scripts: make a synthetic clip, edit it without and with control, plot
# both reports. Usage (sourced): run_example OUT_DIR SYNTH_ARGS...
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
pbve=${PBVE:-$root/build/release/bin/pbve}

run_example() {
  local out=$1
  shift
  mkdir -p "$out"
  "$pbve" synth "$@" "$out"
  "$pbve" edit "$out/scene.yaml" --no-control -o "$out/unconstrained.mp4" --report "$out/unconstrained.json"
  "$pbve" edit "$out/scene.yaml" -o "$out/edited.mp4" --report "$out/report.json"
  "$pbve" plot "$out/unconstrained.json" "$out/report.json" --labels unconstrained,constrained -o "$out/plot.png"
  echo
  echo "edited video:         $out/edited.mp4"
  echo "report:               $out/report.json"
  echo "plot:                 $out/plot.png"
  echo "unconstrained video:  $out/unconstrained.mp4"
}
