"""Task and tracker registries, spec parsing, CLI list/describe and error messages."""
import json
import os

import gymnasium
import numpy as np
import pytest

import doabench
from doabench.cli.main import main
from doabench.envs.spec import spec_from_dict
from doabench.errors import ConfigError, NotFoundError


def test_builtin_tasks_and_grid_cells_are_registered_with_gymnasium():
    tasks = doabench.available_tasks()
    for required in ("sim-demo", "sim-grid", "sim-train", "sim-t60-0.9-snr-5", "sim-t60-0-snr-30", "sim-t60-1.5-snr-15"):
        assert required in tasks
        assert tasks[required].gym_id in gymnasium.registry
    cells = [t for t in tasks if t.startswith("sim-t60-")]
    assert len(cells) == 18
    grid = tasks["sim-grid"]
    assert grid.episodes == 18 * 20  # v1: 20 episodes per cell
    cell = tasks["sim-t60-0.9-snr-5"]
    assert cell.params["scene"]["t60"] == [0.9, 0.9] and cell.params["scene"]["snr"] == [5.0, 5.0]


def test_gym_id_and_plain_id_resolve_to_the_same_spec():
    assert doabench.get_task_spec("doabench/sim-demo-v2") is doabench.get_task_spec("sim-demo")


def test_unknown_task_lists_close_matches():
    with pytest.raises(NotFoundError, match="did you mean 'sim-demo'"):
        doabench.get_task_spec("sim-dmeo")


def test_spec_validation_errors_are_clear():
    with pytest.raises(ConfigError, match="missing version"):
        spec_from_dict({"id": "x", "kind": "simulated"})
    with pytest.raises(ConfigError, match=r"\[grid\] needs"):
        spec_from_dict({"id": "g", "version": 0, "kind": "simulated", "grid": {"t60": [0.3]}})


def test_register_task_from_a_file_without_editing_doabench(tmp_path):
    f = tmp_path / "my-task.toml"
    f.write_text('id = "my-task-xyz"\nversion = 3\nkind = "simulated"\nepisodes = 2\n[speech]\ncorpus = "embedded"\n')
    specs = doabench.register_task(f)
    assert specs[0].gym_id == "doabench/my-task-xyz-v3"
    assert "doabench/my-task-xyz-v3" in gymnasium.registry


def test_tracker_registry_decorator_and_module_path():
    @doabench.register_tracker("toy-const-registry-test")
    class Toy(doabench.Tracker):
        observation_spec = doabench.ObservationSpec.of(("srp",))

        def step(self, observation):
            return np.array([0.0, 0.0, 1.0])

    t = doabench.make_tracker("toy-const-registry-test")
    assert isinstance(t, Toy) and t.name == "toy-const-registry-test"
    t2 = doabench.make_tracker("doabench.trackers.srp:SrpMaxTracker:8x16")
    assert t2.resolution == (8, 16)
    with pytest.raises(NotFoundError, match="did you mean 'srp-max'"):
        doabench.make_tracker("srp-mux")
    with pytest.raises(ConfigError):
        doabench.register_tracker("bad", object)


def test_srp_max_options_and_describe(capsys):
    assert main(["describe", "--tracker", "srp-max:32x64", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["resolution"] == "32x64" and d["causal"] is True and d["parameters"] == 0
    assert {"parameters", "causal", "receptive_field_frames", "features"} <= set(d)


def test_cli_list_and_bad_ids(capsys):
    assert main(["list", "tasks"]) == 0
    assert "sim-t60-0.9-snr-5" in capsys.readouterr().out
    assert main(["list", "trackers"]) == 0
    assert "srp-kalman" in capsys.readouterr().out
    assert main(["describe", "--tracker", "srp-mx"]) == 2
    err = capsys.readouterr().err
    assert "unknown tracker 'srp-mx'" in err and "srp-max" in err and "Traceback" not in err
    assert main(["describe", "--tracker", "srp-max", "--tracker-opt", "novalue"]) == 2
    assert "key=value" in capsys.readouterr().err


def test_list_trackers_gives_whole_descriptions(capsys):
    """A description is its docstring's whole first paragraph, never its first line cut mid-sentence."""
    from doabench.trackers.registry import available_trackers

    assert main(["list", "trackers"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()}
    trackers = available_trackers()
    assert set(lines) == set(trackers)
    for name, cls in trackers.items():
        if cls.__module__.startswith(("doabench.", "doabench_baselines.")):  # not the tests' plug-ins
            assert lines[name].rstrip().endswith((".", ".)")), lines[name]
    assert lines["srp-kalman-cv"].endswith("a tracker that models motion (srp-kalman is a random walk and trails a "
                                           "walking talker).")


def _parsers(parser):
    """``parser`` and every subcommand's parser below it, with their command names."""
    import argparse

    yield parser.prog, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_help_texts_print_a_percent_sign_once():
    """argparse expands ``%%`` in an option's help but prints a description as written."""
    from doabench.cli.main import build_parser

    helps = {prog: parser.format_help() for prog, parser in _parsers(build_parser())}
    assert len(helps) > 15 and not [prog for prog, text in helps.items() if "%%" in text]
    assert "95% interval" in " ".join(helps["doabench compare"].split())


def test_srp_kalman_smooths_outliers_on_the_grid():
    from doabench.arrays import get_array

    k = doabench.make_tracker("srp-kalman:8x16")
    k.reset(get_array("nao"))
    srp = np.zeros((8, 16), np.float32)
    srp[4, 4] = 1.0
    first = k.step({"srp": srp, "vad": 1})
    for _ in range(5):
        k.step({"srp": srp, "vad": 1})
    outlier = np.zeros((8, 16), np.float32)
    outlier[1, 12] = 1.0
    after = k.step({"srp": outlier, "vad": 1})
    # one outlying maximum moves the track by much less than the jump itself
    jump = np.degrees(np.arccos(np.clip(first @ doabench.trackers.srp.grid_unit_vectors(8, 16).reshape(-1, 3)[1 * 16 + 12], -1, 1)))
    moved = np.degrees(np.arccos(np.clip(first @ after, -1, 1)))
    assert moved < 0.2 * jump
    # a silent (all-zero) map holds the estimate
    assert np.allclose(k.step({"srp": np.zeros((8, 16), np.float32), "vad": 0}), after)


@pytest.mark.parametrize("episodes", [0, -3])
def test_a_task_spec_with_no_episodes_is_refused(episodes):
    from doabench.envs.spec import spec_from_dict

    with pytest.raises(ConfigError):
        spec_from_dict({"id": "x-empty", "version": 0, "kind": "simulated", "episodes": episodes})
    with pytest.raises(ConfigError):
        spec_from_dict({"id": "x-grid", "version": 0, "kind": "simulated",
                        "grid": {"t60": [0.2], "snr": [5], "episodes_per_cell": episodes}})


def test_broken_files_on_the_task_path_only_break_their_own_task(tmp_path):
    import subprocess
    import sys

    good = 'id = "{id}"\nversion = 0\nkind = "simulated"\nepisodes = 1\n'
    (tmp_path / "x-good.toml").write_text(good.format(id="x-good"))
    (tmp_path / "x-bad.toml").write_text("id = \"x-bad\"\nversion = [\n")
    (tmp_path / "x-dup.toml").write_text(good.format(id="sim-demo"))
    env = {**os.environ, "DOABENCH_TASK_PATH": os.pathsep.join([str(tmp_path), str(tmp_path / "missing")])}

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "doabench.cli.main", *args], capture_output=True, text=True,
                              env=env, cwd=tmp_path)

    r = cli("--version")
    assert r.returncode == 0 and "Traceback" not in r.stderr
    assert "x-bad.toml" in r.stderr and "missing" in r.stderr and "x-dup.toml" in r.stderr
    r = cli("describe", "--task", "x-good")
    assert r.returncode == 0, r.stderr
    for task in ("x-bad", "sim-demo"):
        r = cli("describe", "--task", task)
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert r.stderr.strip().splitlines()[-1].startswith("doabench describe: error:")


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["list", "tasks"], ["list", "trackers"],
                                  ["describe", "--tracker", "srp-max"]])
def test_commands_that_need_no_tensors_do_not_import_torch(argv):
    """Start-up: torch's import alone takes about 1.4 s; these commands never touch a tensor."""
    import subprocess
    import sys

    code = ("import sys\nfrom doabench.cli.main import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "print('TORCH', 'torch' in sys.modules)" % (argv,))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "TORCH False" in out.stdout, out.stdout[-500:] + out.stderr[-2000:]


def test_a_misspelt_task_option_is_refused_with_the_nearest_name():
    import doabench
    from doabench.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown task option 'librispeach'; did you mean 'librispeech'"):
        doabench.run(tracker="srp-max:4x8", task="sim-demo", episodes=1, progress=False, librispeach="/data")
    # another kind's option (one command line serves every kind) and an option not given pass
    quick = {"duration_s": 2.0, "n_points": 8}
    doabench.run(tracker="srp-max:4x8", task="sim-demo", episodes=1, progress=False, scene_overrides=quick,
                 locata_root=None, split=None)


def test_older_task_versions_stay_runnable_and_an_unknown_version_names_those_that_exist(tmp_path):
    """sim-pauses v3 (120 episodes) is the task; v2 (20 episodes) runs by its versioned id, the
    Gymnasium way, and its results stay readable; a version that does not exist is one line."""
    import gymnasium

    from doabench.envs.registry import get_task_spec, task_reference, task_versions

    latest, old = get_task_spec("sim-pauses"), get_task_spec("doabench/sim-pauses-v2")
    assert (latest.version, latest.episodes) == (3, 120) and (old.version, old.episodes) == (2, 20)
    assert get_task_spec("sim-pauses-v2") is old and sorted(task_versions("sim-fan")) == [1, 2, 3]
    assert task_reference(old) == "sim-pauses-v2" and task_reference(latest) == "sim-pauses"
    assert gymnasium.spec("doabench/sim-pauses-v2").kwargs["task"] == "doabench/sim-pauses-v2"
    with pytest.raises(NotFoundError, match=r"no version 7 \(registered: v2, v3"):
        get_task_spec("doabench/sim-pauses-v7")
    # a file on the task path cannot add a newer version of a built-in task
    (tmp_path / "x.toml").write_text('id = "sim-demo"\nversion = 99\nkind = "simulated"\nepisodes = 1\n')
    from doabench.envs.registry import register_task

    with pytest.raises(ConfigError, match="defined|registered"):
        register_task(tmp_path / "x.toml")
    assert get_task_spec("sim-demo").version != 99


@pytest.mark.parametrize("argv", [
    ["run", "--tracker", "srp-max", "--task", "sim-grid-v99", "--out", "{tmp}"],
    ["sweep", "--trackers", "srp-max", "--tasks", "sim-demo,doabench/sim-grid-v99", "--out", "{tmp}"],
    ["make-dataset", "--task", "sim-grid-v99", "--out", "{tmp}/d.h5"],
    ["train", "--tracker", "cross3d", "--task", "doabench/sim-grid-v99", "--out", "{tmp}/t"],
    ["describe", "--task", "sim-grid-v99"],
    ["simulate", "--task", "sim-grid-v99", "--out", "{tmp}/s"],
    ["plot", "maps", "--task", "sim-grid-v99", "--frame", "0", "--out", "{tmp}/m"],
], ids=lambda argv: argv[0] if argv[0] != "plot" else "plot-maps")
def test_every_entry_point_refuses_an_unknown_task_version_in_one_line(argv, tmp_path, capsys):
    """A typed task id with a version that does not exist: exit 2, one line naming the versions
    there are, nothing written."""
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "task 'sim-grid' has no version 99 (registered: v2;" in err, err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("call", [
    lambda: doabench.get_task_spec("doabench/sim-grid-v99"),
    lambda: doabench.run(tracker="srp-max", task="sim-grid-v99", episodes=1, progress=False),
    lambda: __import__("doabench.envs.env", fromlist=["DoaEnv"]).DoaEnv("doabench/sim-grid-v99"),
], ids=["get_task_spec", "run", "DoaEnv"])
def test_the_python_entry_points_refuse_an_unknown_task_version(call):
    with pytest.raises(NotFoundError, match=r"task 'sim-grid' has no version 99 \(registered: v2;"):
        call()


def test_gymnasium_make_names_the_versions_that_exist():
    with pytest.raises(gymnasium.error.VersionNotFound, match=r"`v99` for environment `doabench/sim-grid` doesn't exist.* \[ `v2` \]"):
        gymnasium.make("doabench/sim-grid-v99")
    with pytest.raises(NotFoundError, match=r"task 'sim-fan' has no version 9 \(registered: v1, v2, v3;"):
        doabench.get_task_spec("sim-fan-v9")
