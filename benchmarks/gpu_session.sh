#!/usr/bin/env bash
# The work of a lent GPU machine (issue 19's GPU figures, issue 18's runs) in steps that each fit one call of
# the device tool (10 minutes; the machine stays warm 30 s between calls, so the training steps run in the
# background and later calls watch them). Run from the repository root of the copy on the GPU machine, with
# the wheels of the peers JAX's image lacks in .whl/ (jaxmarl 0.2.0, gymnax, gymnasium, farama-notifications):
#
#   benchmarks/gpu_session.sh bench        # versions, a smoke test, env and training throughput
#   benchmarks/gpu_session.sh train K      # `cec reproduce overcooked` (the CPU recipe) + K-1 more zoo builders
#   benchmarks/gpu_session.sh paper        # the paper preset's CEC seed 0, beside it
#   benchmarks/gpu_session.sh wait S       # progress until the reproduction ends or S seconds pass
#   benchmarks/gpu_session.sh crossplay    # cross-play throughput (paper preset)
#   benchmarks/gpu_session.sh pack         # stop the paper run (checkpoint), pack results, policies, curves
#   benchmarks/gpu_session.sh window       # ALL OF IT IN ONE CALL (<= 9 min; docs/gpu.md): the paper
#                                          # preset's profile, four seeds of the paper's CEC recipe (or of
#                                          # another recipe, or the shipped seeds trained further), the new
#                                          # policies exported
#   benchmarks/gpu_session.sh smoke        # `window` end to end at tiny sizes on this machine's CPU (the
#                                          # defaults' code path; minutes): run it before lending a GPU
#
# `window` sizes (environment; the defaults fit one 9-minute call): WINDOW_RECIPE
# (configs/train/cec_overcooked_paper_10m.yaml: the paper's network, PPO table, LR schedule, shaping and
# 100-step training episodes, issue 86) the config of the four seeds, seeds WINDOW_SEED.. (600 for a recipe
# of the paper's network, else 500); WINDOW_INIT empty: fresh seeds, `shipped`: the shipped CEC seeds
# continued (with WINDOW_RECIPE=configs/train/cec_overcooked_cpu.yaml, their recipe), or four comma-separated
# checkpoints continued; WINDOW_TEACHER_ANNEAL (a third of WINDOW_STEPS; only for a recipe with a teacher)
# the env steps over which its teacher weight falls to 0; WINDOW_TRAIN_S (380 for the paper's network, else
# 260) seconds of CEC training, stopped by SIGTERM (the trainer checkpoints and exits); WINDOW_PAPER_S (0 for
# the paper's network, whose seeds are the paper preset's throughput; else 60) of the paper preset at each
# precision of WINDOW_PRECISIONS ("default bfloat16": JAX_DEFAULT_MATMUL_PRECISION, bf16 passes with float32
# accumulation and float32 weights); WINDOW_PROFILE_S (90) for the profile of WINDOW_PROFILE_CONFIG (the
# paper preset) with WINDOW_PROFILE_SET overrides; WINDOW_LR (fresh seeds: the recipe's; continued: 1e-3, two
# restarts at 2e-3 each lost cross-play first, docs/gpu.md) the seeds' LR, annealed to 0 over WINDOW_STEPS
# per seed unless the recipe fixes its own schedule (the paper's: over 3e9, so a window is the first steps of
# the paper's run); WINDOW_STEPS per seed (the paper's network: 20,971,520, twice the CPU reproduction's
# 10.5M, whose milestones 0.125/0.25/0.5 fall on its curve's 2.6M/5.2M/10.5M; else 270M: what 4 seeds at 4M
# env-steps/s on an H200 train in the time left after the compile); WINDOW_BATCH the seeds' batch (the
# paper's network: the paper's 512 envs x 256 steps, 4 epochs x 2 minibatches; else 1024 envs, 2 epochs x
# 16 minibatches); WINDOW_SET extra overrides for every run. A time of 0 skips the profile or the paper
# preset (a second window continuing the first's seeds).
#
# Everything that comes back is written under $OUT (at most 8 files of 16 MiB: tarballs, the paper run's
# checkpoint split in parts). CEC_GIT_REV names the commit the copy was made from (the copy has no .git).
set -uo pipefail
OUT=${OUT:-/tmp/gpu-out}
WORK=runs/reproduce/overcooked-cpu
REPORT=benchmarks/results/overcooked/cpu
PAPER_RUN=runs/paper/cec-paper-s0
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
mkdir -p "$OUT" runs

if [ -d .whl ] && [ ! -d /tmp/site ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
fi
export PYTHONPATH=/tmp/site:$PWD
PY=${PYTHON:-python3}
cec() { "$PY" -m apps.cli "$@"; }

# The report is in the tracked tree, which the next call's sync resets: it must come back in the call that
# sees the reproduction end (`wait` does this).
pack_overcooked() {
    if [ -f $WORK/zoo/zoo.yaml ]; then
        names=$(python3 -c "import yaml; print(' '.join('--name ' + e['name'] for e in \
yaml.safe_load(open('$WORK/zoo/zoo.yaml'))['policies'] if e['algorithm'] == 'cec'))")
        # shellcheck disable=SC2086
        cec zoo export $WORK/zoo/zoo.yaml --out runs/shipped $names
    fi
    tar czf "$OUT/overcooked-cpu.tgz" --exclude='checkpoints' $REPORT $WORK runs/*.log runs/shipped 2>/dev/null
}

case "${1:-}" in
bench)
    nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
    python3 -c "import jax, flax, optax, numpy; print('jax', jax.__version__, 'flax', flax.__version__, \
'optax', optax.__version__, 'numpy', numpy.__version__, jax.devices())"
    cec train --config configs/train/quick_cpu.yaml --quiet run_dir=/tmp/smoke total_env_steps=8192 || exit 1
    echo "== env throughput (ours vs JaxMARL 0.2.0)"
    timeout 170 python3 benchmarks/env_throughput.py --n 4096 65536 --repeats 3 --out "$OUT/env_throughput_gpu.json"
    echo "== training throughput, paper preset in CEC mode"
    timeout 170 python3 benchmarks/train_throughput.py --presets paper --batches 512x256 --updates 2 --repeats 3 \
        --out "$OUT/train_throughput_gpu.json"
    ;;
train)
    k=${2:-6}
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.08
    setsid nohup python3 -m apps.cli reproduce overcooked > runs/repro-main.log 2>&1 < /dev/null &
    for _ in $(seq 1 60); do [ -f $WORK/spec.yaml ] && break; sleep 1; done
    for i in $(seq 2 "$k"); do
        sleep 2
        setsid nohup python3 -m apps.cli zoo build $WORK/spec.yaml --out $WORK/zoo > "runs/repro-$i.log" 2>&1 < /dev/null &
    done
    sleep 60
    tail -n 3 runs/repro-*.log
    ;;
paper)
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.5  # 0.3 failed: autotuning asked for 10 GB at 512 x 256
    if [ -d $PAPER_RUN/cec-overcooked-generator-s0 ]; then
        args=(--resume $PAPER_RUN/cec-overcooked-generator-s0)
    else
        args=(--config configs/train/cec_overcooked.yaml run_dir=$PAPER_RUN seed=0)
    fi
    setsid nohup python3 -m apps.cli train "${args[@]}" > runs/paper.log 2>&1 < /dev/null &
    sleep 45
    tail -n 5 runs/paper.log
    ;;
wait)
    end=$((SECONDS + ${2:-540}))
    while [ $SECONDS -lt $end ]; do
        pgrep -f "apps.cli reproduce" > /dev/null || { echo "reproduction ended"; break; }
        sleep 30
        echo "--- $(date +%T): $(grep -h 'update' runs/repro-*.log | tail -n 1)"
        ls $WORK/zoo/runs 2>/dev/null | wc -l
    done
    tail -n 25 runs/repro-main.log
    [ -f runs/paper.log ] && tail -n 3 runs/paper.log
    pgrep -f "apps.cli reproduce" > /dev/null || pack_overcooked
    ;;
pack)
    if pkill -TERM -f "apps.cli train"; then  # the paper run saves a checkpoint at the end of its call
        for _ in $(seq 1 120); do pgrep -f "apps.cli train" > /dev/null || break; sleep 1; done
    fi
    pack_overcooked
    for run in "$PAPER_RUN"/*/; do  # config, metrics and the latest checkpoint only (38 MB for the paper net)
        [ -d "$run/checkpoints" ] || continue
        latest=$(ls "$run/checkpoints" | sort | tail -n 1)
        tar cf - -C "$run" config.yaml metrics.csv "checkpoints/$latest" | split -b 15M - "$OUT/paper-run.tar.part-"
    done
    ls -la "$OUT"
    ;;
smoke)
    # `window` with its defaults' code path at tiny sizes (4 envs x 16 steps per seed), on this machine; the
    # training ends at WINDOW_STEPS (its SIGTERM, 900 s, only if the compile takes that long: 150 s did not
    # reach the first update beside a training run on 2 cores), the export and pack run as on the GPU
    export PYTHON=${PYTHON:-$PWD/.venv/bin/python}
    export OUT WINDOW_TRAIN_S=${WINDOW_TRAIN_S:-900} WINDOW_PROFILE_S=${WINDOW_PROFILE_S:-60}
    export WINDOW_STEPS=${WINDOW_STEPS:-2048} WINDOW_BATCH=${WINDOW_BATCH-num_envs=4 num_steps=16}
    export WINDOW_PROFILE_SET=${WINDOW_PROFILE_SET-num_envs=4 num_steps=16}
    bash "$0" window
    ;;
window)
    RECIPE=${WINDOW_RECIPE:-configs/train/cec_overcooked_paper_10m.yaml}
    # what the recipe is: the paper's network (its batch, seeds and steps below) and whether it has a teacher
    read -r PAPER_NET HAS_TEACHER <<< "$("$PY" -c "
from cec.config import load_config
from cec.training.config import TrainConfig
c = load_config(TrainConfig, '$RECIPE')
print(int(c.network == 'paper' and c.network_overrides is None), int(c.ppo.teacher_coef > 0))")"
    if [ "$PAPER_NET" = 1 ]; then
        T_TRAIN=${WINDOW_TRAIN_S:-380} T_PAPER=${WINDOW_PAPER_S:-0} STEPS=${WINDOW_STEPS:-20971520}
        SEED=${WINDOW_SEED:-600} DEFAULT_BATCH="num_envs=512 num_steps=256"
    else
        T_TRAIN=${WINDOW_TRAIN_S:-260} T_PAPER=${WINDOW_PAPER_S:-60} STEPS=${WINDOW_STEPS:-270000000}
        SEED=${WINDOW_SEED:-500} DEFAULT_BATCH="num_envs=1024 ppo.update_epochs=2 ppo.num_minibatches=16"
    fi
    T_PROFILE=${WINDOW_PROFILE_S:-90} INIT=${WINDOW_INIT:-}
    PROFILE_CONFIG=${WINDOW_PROFILE_CONFIG:-configs/train/cec_overcooked.yaml}
    read -r -a PRECISIONS <<< "${WINDOW_PRECISIONS-default bfloat16}"
    read -r -a PROFILE_SET <<< "${WINDOW_PROFILE_SET:-}"
    read -r -a EXTRA <<< "${WINDOW_SET:-}"
    # The batch of the MLP recipes' seeds: 1024 envs per seed with the time-to-skill recipe's
    # 2 epochs (half the update's arithmetic; the same Adam steps per sample with twice the minibatches: 16 of
    # 8,192 samples): 4.04M env-steps/s for 4 seeds on an H200, against 1.0M at the CPU recipe's 128 envs x 4
    # epochs (benchmarks/results/README.md). The paper's network: the paper's batch (its PPO table).
    read -r -a BATCH <<< "${WINDOW_BATCH-$DEFAULT_BATCH}"
    RUN=runs/window
    log="$OUT/window.log"
    {
        date -u +%FT%TZ; nvidia-smi --query-gpu=name,memory.total --format=csv 2>/dev/null
        "$PY" -c "import jax, flax, optax; print('jax', jax.__version__, 'flax', flax.__version__, \
'optax', optax.__version__, jax.devices())"
        if [ "$T_PROFILE" -gt 0 ]; then
            echo "== 1. training profile of $PROFILE_CONFIG on this device (${T_PROFILE}s at most; the JSON is"
            echo "   written after each stage, so a profile cut short keeps what it measured)"
            XLA_PYTHON_CLIENT_MEM_FRACTION=0.5 timeout "$T_PROFILE" "$PY" benchmarks/train_profile.py \
                --config "$PROFILE_CONFIG" --repeats 2 --set "${PROFILE_SET[@]}" "${EXTRA[@]}" \
                --out "$OUT/train_profile_gpu.json" || echo "profile: exit $?"
        fi
        # The seeds: fresh ones of the recipe, or checkpoints continued (the shipped CEC seeds as
        # cec/shipped/zoo.yaml names them: a directory glob also matched a replaced seed the GPU machine's
        # copy still held) at a restarted LR of 1e-3.
        train=(seed="$SEED" num_seeds=4 total_env_steps="$STEPS")
        if [ "$INIT" = shipped ]; then
            INIT=$("$PY" -c "import yaml; print(','.join('cec/shipped/' + e['checkpoint'] for e in \
yaml.safe_load(open('cec/shipped/zoo.yaml'))['policies'] if e['algorithm'] == 'cec'))")
        fi
        if [ -n "$INIT" ]; then train+=(init_from="$INIT" ppo.lr="${WINDOW_LR:-0.001}")
        elif [ -n "${WINDOW_LR:-}" ]; then train+=(ppo.lr="$WINDOW_LR"); fi
        # A teacher's weight (where the recipe has one) falls to 0 over a third of the steps: at this batch
        # (8x the CPU recipe's samples per Adam step) about the Adam steps of the CPU recipe's whole 1,280
        # updates, over which lever (s) (research/diary/reproduce_overcooked.md) scored above a teacher gone at 960.
        if [ "$HAS_TEACHER" = 1 ]; then train+=(ppo.teacher_anneal_env_steps="${WINDOW_TEACHER_ANNEAL:-$((STEPS / 3))}"); fi
        echo "== 2. four seeds of $RECIPE ${INIT:+continued from $INIT }(one process, SIGTERM after ${T_TRAIN}s)"
        timeout -s TERM -k 60 "$T_TRAIN" "$PY" -m apps.cli train --config "$RECIPE" "${train[@]}" "${BATCH[@]}" \
            checkpoint.every_updates=50 'checkpoint.milestones=[0.125,0.25,0.5,0.75,1.0]' \
            run_dir=$RUN name=cec-window "${EXTRA[@]}"
        echo "training: exit $? (124: stopped by the window's SIGTERM, after its checkpoint)"
        echo "== 3. export: every seed at each milestone and at the last checkpoint (the paper's network: at the"
        echo "   middle milestone and the last, 11 MB a policy: what comes back holds 8 parts of 15 MiB)"
        "$PY" - "$RUN/cec-window" "$SEED" "$PAPER_NET" <<'PYEOF'
import sys, yaml
from pathlib import Path
from cec.checkpoints import CheckpointStore
run, seed, paper_net = Path(sys.argv[1]).resolve(), int(sys.argv[2]), sys.argv[3] == "1"
saved = CheckpointStore(run, keep_last=1).list()
if paper_net and len(saved) > 2:
    saved = [saved[(len(saved) - 1) // 2], saved[-1]]
entries = [
    {"name": f"cec-gpu-s{seed + i}-u{c.update}", "algorithm": "cec", "seed": seed + i, "checkpoint": str(c.path)}
    for c in saved
    for i in range(4)
]
(run.parent / "zoo.yaml").write_text(yaml.safe_dump({"policies": entries}))
print(len(entries), "policies:", ", ".join(e["name"] for e in entries))
PYEOF
        cec zoo export $RUN/zoo.yaml --out $RUN/exported
        tar czf - $RUN/exported $RUN/zoo.yaml $RUN/cec-window/metrics.csv $RUN/cec-window/config.yaml \
            | split -b 15M - "$OUT/cec-window.tgz.part-"
        ls -la "$OUT"
        if [ "$T_PAPER" -gt 0 ]; then
            for precision in "${PRECISIONS[@]}"; do
                echo "== 4. the paper preset's training throughput, matmul precision $precision (${T_PAPER}s)"
                if [ "$precision" = default ]; then prec=(env -u JAX_DEFAULT_MATMUL_PRECISION)
                else prec=(env JAX_DEFAULT_MATMUL_PRECISION="$precision"); fi
                "${prec[@]}" XLA_PYTHON_CLIENT_MEM_FRACTION=0.5 timeout -s TERM -k 30 "$T_PAPER" "$PY" -m apps.cli \
                    train --config configs/train/cec_overcooked.yaml run_dir="/tmp/window-paper-$precision" \
                    "${EXTRA[@]}"
                echo "paper preset ($precision): exit $?"
                cp /tmp/window-paper-"$precision"/*/metrics.csv "$OUT/paper_metrics_$precision.csv"
            done
        fi
        date -u +%FT%TZ
    } > "$log" 2>&1
    ls -la "$OUT"; tail -n 40 "$log"
    ;;
crossplay)
    python3 benchmarks/crossplay_throughput.py --preset paper --out "$OUT/crossplay_throughput_gpu.json"
    ;;
*)
    sed -n 2,36p "$0"
    exit 2
    ;;
esac
