"""The speed benchmarks keep their raw files beside their tables (benchmarks/speed_archive.py), and every table they
write is rendered from the archived rows.json alone, so it can be rendered again from the archive and compared."""

import gzip
import random
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path

import pytest

from script_modules import BENCHMARKS, load_script

ROOT = BENCHMARKS.parent
SPEED = ("ppo_speed", "td3_speed", "time_to_score", "multiseed")  # the benchmarks that archive their raw files
STARTED = datetime(2026, 11, 22, 3, 0, tzinfo=UTC)
MACHINE = {
    "cpu": "AMD EPYC 7B13",
    "cores": "2 logical (2 usable)",
    "usable_cores": 2,
    "memory": "8 GiB",
    "os": "Linux 6.1",
    "python": "3.11.9",
    "gpu": None,
    "load_average_1_5_15_min": [0.1, 0.2, 0.3],
}
VERSIONS = {"canter": "0.1.0", "jax": "0.10.2", "envpool": "1.2.5", "mujoco": "3.6.0", "stable-baselines3": "2.9.2"}


def _script(name: str):
    return load_script(f"{name}_run", BENCHMARKS / name / "run.py")


speed_archive = load_script("speed_archive", BENCHMARKS / "speed_archive.py")


def _write(path: Path, text: str = "x") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_the_archive_keeps_logs_and_run_files_and_leaves_checkpoints_and_big_files(tmp_path):
    runs, dest = tmp_path / "runs", tmp_path / "logs" / "20261122-030000"
    run = runs / "canter-fast__s0" / "HalfCheetah-v4__ppo__fast__s0__20261122-030001-ab12"
    kept = [
        "canter-fast__s0/train.log",
        "canter-fast__s0/eval.log",
        "canter-fast__s0/eval.json",
        f"canter-fast__s0/{run.name}/summary.json",
        f"canter-fast__s0/{run.name}/versions.json",
        f"canter-fast__s0/{run.name}/config.toml",
        f"canter-fast__s0/{run.name}/metrics.csv",
        "sb3__s0/train.json",
    ]
    left = [
        f"canter-fast__s0/{run.name}/checkpoints/ckpt_00001000.npz",
        f"canter-fast__s0/{run.name}/tb/events.out.tfevents.1",
        "sb3__s0/model/model.zip",
        "rows.json",  # the run folder's own copy; the archive writes its own
    ]
    for name in kept + left:
        _write(runs / name)
    _write(runs / "long" / "metrics.csv", "0," * speed_archive.FILE_LIMIT)  # kept gzipped
    (runs / "random.log").write_bytes(random.Random(0).randbytes(speed_archive.FILE_LIMIT + 1))  # left out
    content = speed_archive.record("test", STARTED, {"steps": 10}, [{"tool": "a", "process_wall": 2.5, "sps": 400.0}])

    written = speed_archive.archive(runs, dest, content, MACHINE)

    assert sorted(str(p.relative_to(dest)) for p in written) == sorted(
        [*kept, "long/metrics.csv.gz", "rows.json", "machine.json"]
    )
    assert gzip.decompress((dest / "long" / "metrics.csv.gz").read_bytes()) == b"0," * speed_archive.FILE_LIMIT
    assert speed_archive.load(dest) == (content, MACHINE)
    assert content["started"] == "2026-11-22T03:00:00+00:00" and content["rows"][0]["sps"] == 400.0
    assert speed_archive.logs_dir(tmp_path / "results.md", content) == tmp_path / "logs" / "20261122-030000"
    with pytest.raises(ValueError, match="lacks sps"):
        speed_archive.record("test", STARTED, {}, [{"process_wall": 2.5}])


def _ppo_content(ppo) -> dict:
    def row(tool, sps, wall, evaluation):
        return ppo.Row(tool, 0, True, steps=1_000_000, process_wall=wall, sps=sps, eval_mean=evaluation, eval_std=1.0)

    rows = [row("sb3", 1734.2, 581.9, 5304.3), row("canter-cleanrl", 10648.4, 100.6, 4628.0)]
    rows.append(row("canter-fast", 31236.0, 40.2, 1467.0))
    settings = {"total_steps": 1_000_000, "seeds": [0], "tools": list(ppo.TOOLS), "sb3_threads": 2}
    content = speed_archive.record("ppo_speed", STARTED, settings | {"versions": VERSIONS}, [r.__dict__ for r in rows])
    return content | {"command": ["run.py"]}


def test_the_readme_headline_is_rendered_from_an_archived_rows_json(tmp_path):
    ppo = _script("ppo_speed")
    folder = tmp_path / "logs" / "20261122-030000"
    (tmp_path / "runs").mkdir()
    speed_archive.archive(tmp_path / "runs", folder, _ppo_content(ppo), MACHINE)
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- bench-headline -->\nold table\n<!-- /bench-headline -->\n\nafter\n")

    assert ppo.write_headline(folder, check=True, readme=readme) == 1, "a stale headline must fail the check"
    assert ppo.write_headline(folder, check=False, readme=readme) == 0
    assert ppo.write_headline(folder, check=True, readme=readme) == 0

    text = readme.read_text()
    assert text.startswith("intro\n<!-- bench-headline -->\nHalfCheetah-v4, 1M steps, seed 0, 2-core AMD EPYC 7B13 ")
    assert text.endswith("\n\n<!-- /bench-headline -->\n\nafter\n") and "old table" not in text
    prose = " ".join(text.split())
    assert "with no GPU, 2026-11-22, each tool a whole process run one after another by `make bench`" in prose
    assert f"raw logs: [{folder}]({folder})" in prose and ppo.headline_logs(text) == folder
    local = _ppo_content(ppo) | {"command": ["run.py", "--sb3-python", "/home/me/sb3/bin/python", "--seeds", "0"]}
    local_caption = " ".join(ppo.headline(local, MACHINE, "logs").split())
    assert "by `benchmarks/ppo_speed/run.sh --seeds 0`" in local_caption, "paths on the machine that ran stay out"
    assert ppo.settings_args(["--out-dir=/tmp/x", "--only", "sb3", "--canter", "c"]) == ["--only", "sb3"]
    in_repo = ppo.headline(_ppo_content(ppo), MACHINE, "benchmarks/ppo_speed/logs/20261122-030000")
    assert all(len(line) <= 120 for line in in_repo.splitlines())
    assert (
        "| tool / preset | SPS (compile excluded) | vs SB3 | process wall | eval return (10 eps, deterministic) |\n"
        "|---|---:|---:|---:|---:|\n"
        "| Stable-Baselines3 2.9.2 PPO, CleanRL settings | 1,734 | 1.0x | 582 s | 5304 |\n"
        "| canter `--preset cleanrl` (same settings, 1 env) | 10,648 | **6.1x** | 101 s | 4628 |\n"
        "| canter default `fast` preset (16 envs) | 31,236 | **18.0x** | 40 s | 1467 |\n"
    ) in text


def _contents() -> dict[str, tuple]:
    """One synthetic rows.json record per speed benchmark, with the module that renders it."""
    ppo, td3, tts, multi = (_script(name) for name in SPEED)
    td3_row = td3.Row("canter td3", True, steps=30_000, process_wall=120.0, sps=250.0, steady_sps=262.0)
    td3_row.warmup_sps, td3_row.compile, td3_row.cpu_seconds = 900.0, 4.0, 230.0
    tts_row = {"env": "Hopper-v5", "seed": 0, "steps": 2_501_508, "process_wall": 162.0, "sps": 16442.0}
    tts_row |= {"compile": 3.3, "eval_mean": 3282.0, "eval_std": 13.0, "load_before": 0.1}
    multi_rows = [
        multi.Row("one", [0], 60.0, 110.0, 200_000, [4000.0], [3.0], [900.0], 0.1),
        multi.Row("group", [0, 1], 100.0, 190.0, 400_000, [2500.0, 2500.0], [3.5], [900.0, 950.0], 0.1),
    ]
    multi_settings = {"env": "Hopper-v5", "preset": "fast", "sets": [], "total_steps": 200_000, "seeds": [0, 1]}
    return {
        "ppo_speed": (ppo, _ppo_content(ppo)),
        "td3_speed": (
            td3,
            speed_archive.record(
                "td3", STARTED, {"total_steps": 30_000, "learning_starts": 5000, "seed": 0}, [asdict(td3_row)]
            ),
        ),
        "time_to_score": (
            tts,
            speed_archive.record("tts", STARTED, {"versions": VERSIONS, "seeds": [0], "minutes": 3.0}, [tts_row]),
        ),
        "multiseed": (
            multi,
            speed_archive.record(
                "multiseed", STARTED, multi_settings | {"versions": VERSIONS}, [asdict(r) for r in multi_rows]
            ),
        ),
    }


def _beside(header: str) -> bool:
    cells = [c.strip() for c in header.strip("|").split("|")]
    at = next(i for i, c in enumerate(cells) if "process wall" in c)
    return any("SPS" in c for c in cells[max(at - 1, 0) : at + 2] if c != cells[at])


def test_every_speed_table_shows_process_wall_beside_sps_and_comes_from_rows_json():
    for name, (module, content) in _contents().items():
        rendered = module.tables(content)
        text = module.section(content, MACHINE, f"benchmarks/{name}/logs/20261122-030000")
        assert rendered in text and f"logs and rows.json: benchmarks/{name}/logs/20261122-030000" in text, name
        headers = [line for line in rendered.splitlines() if line.startswith("| ") and "process wall" in line]
        assert headers and all(_beside(h) for h in headers), (name, headers)
    multi, content = _contents()["multiseed"]
    assert "| group | 2 | 1 | 100.0 | 2,500, 2,500 | 190.0 | 400,000 | 4,000 | 3.5 | 1.67× |" in multi.tables(content)


def test_committed_archives_render_the_tables_beside_them():
    """Each committed benchmarks/<name>/logs/<stamp>/ renders a section that stands in its results.md, and the
    README headline, once it names an archive, is the one that archive renders."""
    for rows_json in sorted(p for name in SPEED for p in BENCHMARKS.glob(f"{name}/logs/*/rows.json")):
        module = _script(rows_json.parents[2].name)
        content, machine = speed_archive.load(rows_json.parent)
        section = module.section(content, machine, speed_archive.shown(rows_json.parent))
        assert section in (rows_json.parents[2] / "results.md").read_text(), f"results.md differs from {rows_json}"
    readme = (ROOT / "README.md").read_text()
    ppo = _script("ppo_speed")
    folder = ppo.headline_logs(readme)
    if folder is not None:
        assert ppo.write_headline(folder, check=True) == 0
    for name in README_PARAGRAPHS:
        module = _script(name)
        folder = speed_archive.block_logs(readme, module.README_MARKERS)
        assert folder is not None, f"README.md's {module.README_MARKERS[0].strip()} block names no archive"
        assert module.main(["--readme", str(folder), "--check"]) == 0, name


README_PARAGRAPHS = ("td3_speed", "time_to_score")  # the README paragraphs written with `run.py --readme LOGS`


def test_readme_paragraphs_are_rendered_from_an_archive_and_checked(tmp_path):
    contents = _contents()
    td3, content = contents["td3_speed"]
    sb3 = td3.Row("SB3 TD3", True, steps=30_000, process_wall=300.0, sps=100.0, steady_sps=104.8)
    content = content | {"rows": [*content["rows"], asdict(sb3)], "command": ["run.py", "--total-steps", "30000"]}
    contents["td3_speed"] = (td3, content)
    for name in README_PARAGRAPHS:
        module, content = contents[name]
        folder = tmp_path / name / "logs" / "20261122-030000"
        (tmp_path / name / "runs").mkdir(parents=True)
        speed_archive.archive(tmp_path / name / "runs", folder, content, MACHINE)
        readme = tmp_path / name / "README.md"
        begin, end = module.README_MARKERS
        readme.write_text(f"intro\n{begin}stale\n{end}\n")
        write = speed_archive.write_block
        assert write(folder, module.README_MARKERS, module.readme_text, True, readme, "--readme") == 1, name
        assert write(folder, module.README_MARKERS, module.readme_text, False, readme, "--readme") == 0, name
        assert write(folder, module.README_MARKERS, module.readme_text, True, readme, "--readme") == 0, name
        assert speed_archive.block_logs(readme.read_text(), module.README_MARKERS) == folder, name
    text = " ".join(td3.readme_text(contents["td3_speed"][1], MACHINE, "logs/x").split())
    assert (
        "by `benchmarks/td3_speed/run.py --total-steps 30000` (30,000 steps, learning_starts 5,000, a short probe;"
        in text
    )
    assert "**262** against SB3's **105**, **2.5x**, and the whole processes took 120 s and 300 s." in text
    # canter: 25k warm-up steps at 900 SPS and 975k at 262; SB3 (no warm-up rate): 975k at 104.8
    assert "1M steps take about 62 minutes against SB3's 2.6 hours." in text
    tts, content = contents["time_to_score"]
    more = [content["rows"][0] | {"seed": 1, "eval_mean": 2000.0, "process_wall": 170.0}]
    more.append(content["rows"][0] | {"seed": 2, "eval_mean": 2600.0, "process_wall": 150.0})
    content = content | {"rows": content["rows"] + more, "settings": content["settings"] | {"seeds": [0, 1, 2]}}
    text = " ".join(tts.readme_text(content, MACHINE, "logs/x").split())
    assert "medians over seeds 0,1,2; raw logs: [logs/x](logs/x)): Hopper-v5 scored **2600** in 162 s" in text
    assert "(target 2500: met)." in text
