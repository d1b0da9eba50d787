#!/bin/bash
# The runs behind the tables of docs/benchmark.md ("Results: realistic scenario", held-out seed and city,
# the two real images, the knob sweeps): one `semcityloc benchmark` per row, resumable, then the report with the acceptance
# table and the risk-coverage plot, and each main run's miss_causes.md, and the "Other cameras and cities" checks. About 80 min on 2 cores. Usage: bash benchmarks/benchmark_tables.sh [OUT]
# Needs ../shared/data beside the repository (the Berlin, Den Haag and real-image data).
set -euo pipefail
cd "$(dirname "$0")/.."
S=${SEMCITYLOC:-.venv/bin/semcityloc}
DATA=../shared/data
CITY=$DATA/berlin_lod2_citygml2/3910_5817.gml
R=${1:-runs/tables}
mkdir -p "$R"
for M in semcityloc no-depth silhouette no-refine no-coarse lodloc-wireframe; do
  $S benchmark --city $CITY --queries 100 --method $M --workers 2 --out "$R/berlin_$M"
done
$S benchmark --city $CITY --queries 100 --preset legacy --workers 2 --out "$R/berlin_legacy"
for Q in medium zero-shot; do
  $S benchmark --city $CITY --queries 100 --seg-quality $Q --workers 2 --out "$R/berlin_seg_$Q"
done
[ -f "$R/DenHaag/DenHaag_01.xml" ] || unzip -o -q $DATA/denhaag_lod2/DenHaag_01.zip -x '__MACOSX/*' -d "$R"
for M in semcityloc no-depth; do
  $S benchmark --city $CITY --queries 100 --seed 1 --method $M --workers 2 --out "$R/berlin_s1_$M"
  $S benchmark --city $CITY --queries 100 --seed 2 --method $M --workers 2 --out "$R/berlin_s2_$M"
  $S benchmark --city "$R/DenHaag/DenHaag_01.xml" --queries 50 --method $M --workers 2 --out "$R/denhaag_$M"
done
for S_ in 0 1 2 3 4 5; do
  $S benchmark --dataset $DATA --perception oracle-degraded --seed $S_ --out "$R/real_degraded_s$S_"
done
$S benchmark --dataset $DATA --perception oracle --out "$R/real_oracle"
for BS in "10-20 xy=12,z=17" "20-30 xy=15,z=20" "30-40 xy=18,z=24" "40-50 xy=22,z=27"; do
  set -- $BS
  $S benchmark --city $CITY --queries 50 --prior-extra "$1" --prior-sigma "$2" --workers 2 --out "$R/berlin_prior_$1"
done
for L in 1 2 3; do
  $S benchmark --city generated --lod $L --queries 50 --workers 2 --out "$R/generated_lod$L"
done
$S benchmark --city generated --lod 3 --preset openings --queries 50 --workers 2 --out "$R/generated_lod3_openings"
for KV in "prior_roll_pitch_sigma_deg 0,1,2 rp" "height_change_max_m 0,2,4 height" "depth_model.distortion 0,0.1,0.2 depth"; do
  set -- $KV
  $S sweep --knob "$1" --values "$2" --city $CITY --queries 50 --workers 2 --out "$R/sweep_$3"
done
# "Every draw at once": ten Berlin draws and four of Den Haag, three methods, pooled
for SEED in 0 1 2 3 4 5 6 7 8 9; do
  for M in semcityloc no-depth silhouette; do
    $S benchmark --city $CITY --queries 100 --seed $SEED --method $M --workers 2 --out "$R/draws/berlin_s${SEED}_$M"
  done
done
for SEED in 0 1 2 3; do
  for M in semcityloc no-depth silhouette; do
    $S benchmark --city "$R/DenHaag/DenHaag_01.xml" --queries 50 --seed $SEED --method $M --workers 2 \
      --out "$R/draws/denhaag_s${SEED}_$M"
  done
done
# "Other cameras and cities": cities no stop tuned on, Berlin seed 3 with one knob pushed, a narrow camera
for C in delft rotterdam_subset; do
  $S benchmark --city $DATA/cityjson_nl/$C.json --queries 100 --workers 2 --out "$R/other_$C"
done
for C in Opera-Lyon_CityGML3.0_LOD2_with_xAL3_FreeText 53394517_bldg_6697_2_op_CityGML3; do  # stop 49
  $S benchmark --city $DATA/citygml3/$C.gml --queries 100 --workers 2 --out "$R/other_${C%%_*}"
done
set -f  # the knob values hold [ ]: no file-name globbing of them
for KV in "as_is" "imu2 prior_roll_pitch_sigma_deg=2 prior_roll_pitch_deg=5" \
    "depth2 depth_model.distortion=0.2 depth_model.noise=[0.05,0.1]" \
    "outdated reality.missing_fraction=0.2 reality.new_fraction=0.2" \
    "higher height_range_m=[150,250] nominal_height_m=200" "narrow focal_mm=28" \
    "focal_short focal_error=-0.024" "focal_long focal_error=0.01" \
    "lens05 lens_k1=-0.05" "lens05_unstated lens_k1=-0.05 lens_stated=false" \
    "lens10 lens_k1=-0.1" "lens10_unstated lens_k1=-0.1 lens_stated=false" \
    "flat_eaves reality.overhang_flat_roofs=true" "big_eaves reality.overhang_m=[1,2]" \
    "trees3x reality.tree_m2=100" "map_err2x reality.shift_xy_max_m=2 reality.height_change_max_m=4" \
    "yaw25 prior_yaw_deg=25" "w169 width=640 height=360" "portrait width=384 height=512" \
    "hilly reality.terrain_relief_m=10"; do
  set -- $KV
  NAME=$1; shift
  SETS=(); for KNOB in "$@"; do SETS+=(--set "$KNOB"); done
  $S benchmark --city $CITY --queries 100 --seed 3 --workers 2 ${SETS[@]+"${SETS[@]}"} --out "$R/berlin_s3_$NAME"
done
$S benchmark --city $CITY --queries 100 --seed 3 --workers 2 --set prior_yaw_deg=25 --prior-sigma yaw=9 \
  --out "$R/berlin_s3_yaw25_stated"
$S benchmark --city generated --queries 50 --workers 2 --set oblique_fraction=1 --set 'oblique_pitch_deg=[70,84]' \
  --out "$R/generated_horizontal"
set +f
for F in 18.55 23.77 28; do  # 50, 40 and 34 deg across (the default camera: 70)
  for C in generated $DATA/fuerth_lod2_citygml1/LOD2_4424_5482_solid.gml; do
    $S benchmark --city $C --queries 100 --workers 2 --set focal_mm=$F --out "$R/narrow${F}_$(basename $C .gml)"
  done
done
for E in -0.024 0.01; do
  $S benchmark --city generated --queries 100 --workers 2 --set focal_error=$E --out "$R/generated_focal$E"
done
$S benchmark --city generated --queries 100 --workers 2 --out "$R/generated_as_is"
for K in -0.05 -0.1; do  # a radial lens, stated (undistorted as a photo run does) or taken for pinhole
  for ST in true false; do
    $S benchmark --city generated --queries 100 --workers 2 --set lens_k1=$K --set lens_stated=$ST \
      --out "$R/generated_lens${K}_$ST"
  done
done
# the narrow camera with a height prior good to +-5 m, its sigma left at the default and stated
$S benchmark --city generated --queries 100 --workers 2 --set focal_mm=28 --set prior_height_m=5 --out "$R/narrow_z5"
$S benchmark --city generated --queries 100 --workers 2 --set focal_mm=28 --set prior_height_m=5 \
  --prior-sigma z=2 --out "$R/narrow_z5_stated"
# "A look beyond the volume" (docs/localization.md): the ring's best against the sweep's, per condition
for C in generated $DATA/fuerth_lod2_citygml1/LOD2_4424_5482_solid.gml; do
  for SEED in 0 1; do for COND in trained prior20-30 prior40-50; do
    ${PYTHON:-.venv/bin/python} benchmarks/look_beyond.py --city $C --seed $SEED --condition $COND
  done; done
  for COND in medium zero-shot; do
    ${PYTHON:-.venv/bin/python} benchmarks/look_beyond.py --city $C --seed 1 --condition $COND
  done
done > "$R/look_beyond.jsonl"
for COND in trained prior20-30 prior40-50 zero-shot; do
  ${PYTHON:-.venv/bin/python} benchmarks/look_beyond.py --city $CITY --seed 1 --queries 60 --condition $COND --check-only
done > "$R/look_beyond_berlin.jsonl"
$S report "$R/berlin_semcityloc" "$R/berlin_no-depth" --out "$R/report_acceptance"
$S report "$R"/sweep_rp/* "$R"/sweep_height/* "$R"/sweep_depth/* --out "$R/report_sweeps" --no-html
PY=${PYTHON:-.venv/bin/python}
$PY benchmarks/pooled_draws.py "$R"/draws/berlin_* > "$R/draws/pooled_berlin.md"  # "Every draw at once"
$PY benchmarks/pooled_draws.py "$R"/draws/denhaag_* > "$R/draws/pooled_denhaag.md"
for RUN in berlin_semcityloc berlin_no-depth berlin_silhouette berlin_s1_semcityloc berlin_s2_semcityloc denhaag_semcityloc; do
  $PY benchmarks/miss_causes.py "$R/$RUN" > "$R/$RUN/miss_causes.md"  # why each miss (docs/benchmark.md)
done
