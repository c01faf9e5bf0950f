#!/usr/bin/env bash
# One part of canter's GPU benchmarks (issue 26), each sized to finish within 5 minutes on one H100, compile included
# (`ppo-brax` with no env runs two such parts back to back, and `HUMANOID_MINUTES=7` makes humanoid a longer one):
#
#   bash benchmarks/gpu/run.sh smoke       # install check: jax.devices() and 1 PPO iteration of Hopper-v5 on mjx
#   bash benchmarks/gpu/run.sh ppo-brax    # Brax's own PPO vs canter ppo --preset brax on Brax's ant and humanoid
#   bash benchmarks/gpu/run.sh ppo-brax ant   # one env of it
#   bash benchmarks/gpu/run.sh humanoid    # Humanoid-v5 on mjx for 4 minutes, evaluated during training: time to 6000
#   bash benchmarks/gpu/run.sh seeds       # Hopper-v5 on mjx, 5 vmapped seeds vs 1 seed, the same steps
#   bash benchmarks/gpu/run.sh offpolicy   # td3 and sac on HalfCheetah-v5 on mjx, many envs
#   bash benchmarks/gpu/run.sh precision   # MJX against C MuJoCo on the GPU, its default matmul precision and full float32
#
# The GPU machine cannot reach a registry: the wheels it lacks come in .whl/ (benchmarks/gpu/wheels.sh downloads
# them here) and are installed into /tmp/site at the start. Everything the part prints goes to $OUT/PART.log, and
# its figures, with the device's name, to $OUT/PART.md, for benchmarks/gpu/results.md. OUT defaults to
# benchmarks/gpu/out. Run folders stay in $OUT/runs without their checkpoints (which hold every env's state); the
# device brings back files at most two folders down, so on the device run the parts through session.sh, which packs
# them.
#
# CANTER_GPU_SMOKE=1 shrinks every part to a few envs and steps, to check the script on a CPU (minutes, not figures).
# The sizes below can be changed through the environment variables they read.
set -euo pipefail
cd "$(dirname "$0")/../.."
part=${1:-}
shift || true
case "$part" in
smoke | ppo-brax | humanoid | seeds | offpolicy | precision) ;;
*)
    echo "usage: bash benchmarks/gpu/run.sh smoke|ppo-brax|humanoid|seeds|offpolicy|precision" >&2
    exit 2
    ;;
esac
PY=${PYTHON:-python3}
# shellcheck source=benchmarks/gpu/carried.sh
source benchmarks/gpu/carried.sh # the cd above put us in the repository root
SMOKE=${CANTER_GPU_SMOKE:-0}
OUT=${OUT:-benchmarks/gpu/out}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
RUNS=$OUT/runs
# session.sh's `timeout` sends SIGTERM to this whole process group. Without a trap bash would exit at once, and
# timeout with it, while canter is still finishing its iteration, checkpointing and writing summary.json: the part
# would be summarized and packed without them. With the trap bash waits for the running command, then stops; tee
# ignores the signal, so the log keeps canter's last lines.
# The trap only marks the stop: `timed` then records the process it waited for before it exits, so a cut process
# still has its whole-process time, and no new process starts.
stopping=0
trap 'stopping=1; echo "run.sh: stopped by SIGTERM"' TERM
exec > >(
    trap '' TERM
    exec tee -a "$OUT/$part.log"
) 2>&1
# bash does not wait for a process substitution: at exit, end tee's input and wait for it to write the last lines,
# so that session.sh, packing the log as soon as this exits, has all of it.
tee_pid=$!
trap 'exec >&- 2>&-; wait "$tee_pid"' EXIT

if compgen -G ".whl/*.whl" >/dev/null && [ "${CANTER_GPU_INSTALL:-1}" = 1 ]; then
    install_carried_wheels
    export PYTHONPATH=/tmp/site:$PWD/src
else
    export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONUNBUFFERED=1
# canter keeps compiled programs in ~/.cache/canter/xla for mjx and brax runs, and Brax keeps none: on a machine that
# ran a part before, canter's compile and whole-process times would come from the cache. Every part starts cold.
export CANTER_COMPILE_CACHE=${CANTER_COMPILE_CACHE:-off}

echo "== $part ($(date -u +%FT%TZ), CANTER_GPU_SMOKE=$SMOKE)"
"$PY" - <<'EOF' | tee "$OUT/device.txt"
import jax
print(f"{jax.devices()[0].device_kind} (JAX {jax.__version__}, {jax.default_backend()})")
EOF
# Where the CUDA plugin fails to start, JAX falls back to the CPU with a warning, and a part would spend its whole
# limit there for figures that mean nothing.
if [ "$SMOKE" != 1 ] && ! grep -q ", gpu)" "$OUT/device.txt"; then
    echo "run.sh: JAX is not on a GPU ($(cat "$OUT/device.txt")); CANTER_GPU_SMOKE=1 runs the parts on a CPU" >&2
    exit 1
fi
if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
fi

# Settings of this part, recorded in PART.md; a second run of the part in the same OUT adds its own.
settings() { printf '%s\n' "$@" >>"$OUT/$part.settings"; }
settings "# run.sh $part $* ($(date -u +%FT%TZ), CANTER_COMPILE_CACHE=$CANTER_COMPILE_CACHE)"
# Whole processes, timed from outside (interpreter start, imports, compile, training, evaluations): one JSON line
# per process in $OUT/$part.times, for the like-for-like column of ppo-brax.
timed() {
    local label=$1 start status=0
    shift
    if [ "$stopping" = 1 ]; then exit 143; fi
    start=$(date +%s%N)
    "$@" || status=$?
    printf '{"label": "%s", "seconds": %s, "exit": %d, "stopped": %s}\n' "$label" \
        "$(((($(date +%s%N) - start) / 1000000)))e-3" "$status" "$([ "$stopping" = 1 ] && echo true || echo false)" \
        >>"$OUT/$part.times"
    if [ "$stopping" = 1 ]; then exit 143; fi
    return $status
}
# canter train with what every run here shares: no TensorBoard, one checkpoint at the end, no progress bar.
train() {
    local label=$1
    shift
    settings "canter train $*"
    timed "$label" "$PY" -m canter.cli train "$@" --out-dir "$RUNS/$label" --quiet \
        --set run.tensorboard=false --set run.checkpoint_every=0
}
small() { [ "$SMOKE" = 1 ] && echo "$1" || echo "$2"; }
# MJX_SETS: --set flags for every mjx run. Unset, the solver settings of every archived GPU figure (docs/gpu.md); with
# the XML's own (MJX_SETS="") MJX steps Hopper about 15x slower there, and the parts are not sized for that.
read -r -a mjx_sets <<<"${MJX_SETS-"--set env.solver_iterations=4 --set env.solver_ls_iterations=8"}"
# EVAL_BACKEND: where the mjx parts' evaluations during training play. `auto` plays them on C MuJoCo on the host's
# idle cores (EnvPool where installed, else Gymnasium), on the XML's own model: an MJX evaluation plays its 1000
# steps one after another on the GPU, about 10 ms each on an H100. EVAL_BACKEND=mjx plays them there.
eval_sets=(--set "run.eval_backend=${EVAL_BACKEND:-auto}")

case "$part" in
smoke)
    "$PY" -c "import canter, jax; print('canter imports; devices:', jax.devices())"
    # One iteration: 64 envs x 128 steps (the fast preset's ppo.n_steps).
    train smoke Hopper-v5 --backend mjx "${mjx_sets[@]}" --seed 0 --set env.num_envs="$(small 4 64)" \
        --set ppo.n_steps="$(small 8 128)" --set ppo.minibatch_size="$(small 16 512)" \
        --total-steps "$(small 32 8192)"
    ;;
ppo-brax)
    # Brax's published settings for both trainers (benchmarks/gpu/brax_ppo.py, src/canter/presets/brax.toml), the
    # same env steps (Brax rounds its num_timesteps up to whole epochs; canter trains the steps Brax trained), and
    # a final evaluation of each.
    envs=("$@")
    [ ${#envs[@]} -gt 0 ] || envs=(ant humanoid)
    case "${BRAX_TRAINERS:-both}" in
    both | brax | canter) ;;
    *) echo "run.sh ppo-brax: BRAX_TRAINERS is both, brax or canter, not ${BRAX_TRAINERS}" >&2 && exit 2 ;;
    esac
    for env in "${envs[@]}"; do
        case "$env" in
        ant) timesteps=${BRAX_ANT_STEPS:-10000000} ;;
        humanoid) timesteps=${BRAX_HUMANOID_STEPS:-5000000} ;;
        *) echo "run.sh ppo-brax: no published settings for $env; use ant or humanoid" >&2 && exit 2 ;;
        esac
        smoke_flag=()
        [ "$SMOKE" = 1 ] && smoke_flag=(--smoke) && timesteps=80
        # Three evaluations give Brax two training epochs; the first compiles, so the last epoch's training/sps is
        # its compile-free rate, the figure canter's SPS (its compile left out) compares with.
        # BRAX_TRAINERS=brax or canter runs one side only, for a budget whose two sides do not fit one device call
        # (ant at Brax's full 50M steps): canter then trains the steps of BRAX_RECORD, the brax_ENV.json that Brax's
        # side wrote in an earlier call, or else the steps asked for.
        record=$OUT/brax_$env.json
        if [ "${BRAX_TRAINERS:-both}" != canter ]; then
            settings "python benchmarks/gpu/brax_ppo.py $env --timesteps $timesteps --num-evals 3 ${smoke_flag[*]}"
            timed "brax-$env" "$PY" benchmarks/gpu/brax_ppo.py "$env" --timesteps "$timesteps" --num-evals 3 \
                "${smoke_flag[@]}" --out "$record"
        elif [ -n "${BRAX_RECORD:-}" ]; then
            record=$BRAX_RECORD
        fi
        [ "${BRAX_TRAINERS:-both}" = brax ] && continue
        if [ -f "$record" ]; then
            steps=$("$PY" -c "import json, sys; print(json.load(open(sys.argv[1]))['steps'])" "$record")
            settings "canter trains the $steps env steps Brax trained ($record)"
        else
            steps=$timesteps
            settings "canter trains the $steps env steps asked for (no Brax record)"
        fi
        shrink=()
        if [ "$SMOKE" = 1 ]; then
            shrink=(--set env.num_envs=8 --set ppo.n_steps=10 --set ppo.minibatch_size=40)
        fi
        train "ppo-brax-$env" "$env" --backend brax --preset brax --seed 1 --total-steps "$steps" \
            --eval-every "$steps" --eval-episodes "$(small 4 128)" "${shrink[@]}"
    done
    ;;
humanoid)
    # The humanoid preset on Gymnasium's Humanoid-v5 ported to MJX: Brax's humanoid PPO settings with Brax's
    # exploration noise relative to the action range (net.log_std_init -0.916), a 256-256-256 policy and
    # half-length iterations. On the CPU these cut the env steps to an evaluation of 6000 from about 20M to 8M on
    # seed 0, and four seeds of five got there by 8.1M (benchmarks/gpu/humanoid_cpu/recipes.md, seeds.md). At about
    # 30k env steps/s that is more than the default 4 minutes: HUMANOID_MINUTES=7 runs it to the score, when the
    # device time allows a part that long. HUMANOID_SETS adds `--set` flags on top of the preset.
    num_envs=${HUMANOID_ENVS:-2048}
    read -r -a extra <<<"${HUMANOID_SETS:-}"
    [ "$SMOKE" = 1 ] && num_envs=4 && extra=(--set ppo.n_steps=8 --set ppo.minibatch_size=16 --set ppo.epochs=1)
    train humanoid Humanoid-v5 --backend mjx "${mjx_sets[@]}" --preset humanoid --seed 0 --set env.num_envs="$num_envs" "${extra[@]}" \
        --max-minutes "$(small 3 "${HUMANOID_MINUTES:-4}")" --total-steps "$(small 64 1000000000)" \
        --eval-every "$(small 32 "${HUMANOID_EVAL_EVERY:-1000000}")" --eval-episodes "$(small 2 16)" "${eval_sets[@]}"
    ;;
seeds)
    # The same run as one seed and as 5 vmapped seeds: the same envs per seed and steps per seed.
    # 1024 envs and 500k steps per seed, as on the H100 (results.md): about 90 s for one seed and 110 s for five,
    # cold, so 240 s for the part covers both compiles.
    num_envs=$(small 4 "${SEEDS_ENVS:-1024}")
    steps=$(small 64 "${SEEDS_STEPS:-500000}")
    minibatch=$(small 16 4096)
    for label in one five; do
        seed_flag=(--seed 0)
        [ $label = five ] && seed_flag=(--seeds 0,1,2,3,4)
        train "seeds-$label" Hopper-v5 --backend mjx "${mjx_sets[@]}" "${seed_flag[@]}" --set env.num_envs="$num_envs" \
            --set ppo.n_steps="$(small 8 128)" --set ppo.minibatch_size="$minibatch" --total-steps "$steps"
    done
    ;;
offpolicy)
    # Many envs, large batches and several updates per env step, as FastTD3 does; 2 minutes each by default. On an
    # H100, 1024 envs with 4 updates per vector step made too few updates to learn in minutes; 256 with 16 did.
    num_envs=$(small 4 "${OFFPOLICY_ENVS:-256}")
    read -r -a algos <<<"${OFFPOLICY_ALGOS:-td3 sac}"
    for algo in "${algos[@]}"; do
        train "offpolicy-$algo" HalfCheetah-v5 --backend mjx "${mjx_sets[@]}" --algo "$algo" --seed 0 \
            --set env.num_envs="$num_envs" --set "$algo.batch_size=$(small 32 "${OFFPOLICY_BATCH:-4096}")" \
            --set "$algo.gradient_steps=$(small 1 "${OFFPOLICY_UPDATES:-16}")" \
            --set "$algo.buffer_size=$(small 1000 2000000)" --set "$algo.learning_starts=$(small 16 "$((num_envs * 40))")" \
            --set "$algo.steps_per_call=$(small 8 "$((num_envs * 100))")" \
            --max-minutes "$(small 2 "${OFFPOLICY_MINUTES:-2}")" --total-steps "$(small 48 1000000000)" \
            --eval-every "$(small 32 "${OFFPOLICY_EVAL_EVERY:-500000}")" --eval-episodes "$(small 2 10)" "${eval_sets[@]}"
    done
    ;;
precision)
    # A GPU's default precision for float32 matrix products is TensorFloat-32 (10 bits of mantissa), and MJX's
    # solver and Jacobians are matrix products, so the ports' accuracy measured on a CPU (benchmarks/mjx_equivalence)
    # is measured again here: at the default and at full float32, with the solver settings the parts train with.
    solver=${PRECISION_SOLVER:-4,8}
    read -r -a precision_envs <<<"${PRECISION_ENVS:-Hopper-v5 Humanoid-v5}"
    for precision in default highest; do
        settings "JAX_DEFAULT_MATMUL_PRECISION=$precision CANTER_SOLVER=$solver python benchmarks/mjx_equivalence/measure.py"
        JAX_DEFAULT_MATMUL_PRECISION=$precision CANTER_SOLVER=$solver timed "precision-$precision" \
            "$PY" benchmarks/mjx_equivalence/measure.py "$(small 3 "${PRECISION_STEPS:-100}")" "${precision_envs[@]}" \
            >"$OUT/precision-$precision.table"
        cat "$OUT/precision-$precision.table"
    done
    ;;
esac

find "$RUNS" -type d -name checkpoints -prune -exec rm -rf {} + 2>/dev/null || true
"$PY" benchmarks/gpu/summarize.py "$part" "$OUT"
