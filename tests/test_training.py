"""doabench train: one step learns, resume is exact, the curriculum switches, the speaker split
holds, CLI errors are one line. Tiny synthetic caches and a tiny tracker keep it fast."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import doabench
from doabench.envs.sources import episode_seed
from doabench.features import FeatureKind, register_feature_kind
from doabench.features.kinds import FEATURE_KINDS
from doabench.framing import FrameSpec
from doabench.training.cache import TrajectoryCache, write_item
from doabench.training.data import CachedItems, collate
from doabench.training.recipes import Phase, Recipe, cpu_recipe, paper_recipe
from doabench.training.trainer import TrainOptions, Trainer

M, FRAMES = 4, 8
FS = FrameSpec(window=256, hop=192)
L = FS.window + FS.hop * (FRAMES - 1)


class TinyNet(torch.nn.Module):
    """Causal conv over frames: ``(B, T, C)`` -> ``(B, T, 3)``."""

    def __init__(self, channels: int = M) -> None:
        super().__init__()
        self.conv = torch.nn.Conv1d(channels, 3, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(torch.nn.functional.pad(x.transpose(1, 2), (2, 0)))
        return torch.tanh(y.transpose(1, 2))


def energy_features(audio: torch.Tensor, vad: torch.Tensor) -> dict[str, torch.Tensor]:
    frames = audio.unfold(-1, FS.window, FS.hop)  # (B, M, T, K)
    return {"energy": torch.log(frames.pow(2).mean(-1) + 1e-8).transpose(1, 2)}


#: the kind the tiny tracker reads, registered for each test (its spec names it); the trainer is
#: given energy_features, the same values from the audio
ENERGY = FeatureKind("energy", lambda c: (c.array.n_mics,),
                     compute=lambda stft: torch.log(stft.frames.pow(2).mean(-1) + 1e-8),
                     description="log frame power per microphone")


def use_energy_kind(monkeypatch=None) -> None:
    """Register ENERGY, which the tiny tracker reads: for one test with ``monkeypatch``, else for
    the process (a subprocess or a worker that trains the tiny tracker)."""
    if monkeypatch is not None:
        monkeypatch.setattr(FEATURE_KINDS, "_entries", dict(FEATURE_KINDS.registered()))  # for this test only
    register_feature_kind(ENERGY)


@pytest.fixture(autouse=True)
def energy_kind(monkeypatch):
    use_energy_kind(monkeypatch)


class TinyTracker(doabench.Tracker):
    """Just enough learned tracker for the training protocol."""

    def __init__(self, spec=None, **options):
        super().__init__(spec, **options)
        self.observation_spec = doabench.ObservationSpec.of(("energy",), frame_spec=FS)
        self.network = TinyNet()

    def network_input(self, features):
        return features["energy"]  # (B, T, M)

    def save_weights(self, path, metadata):
        from safetensors.torch import save_file

        save_file(self.network.state_dict(), str(path), metadata={"doabench": json.dumps(metadata)})


def tiny_tracker() -> TinyTracker:
    torch.manual_seed(0)
    return TinyTracker()


def make_cache(folder: Path, n: int, seed: int, mics: int = M, length: int = L, silent_from: int | None = None) -> Path:
    """``silent_from``: voice-inactive from that sample on (a long silence at the end)."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(json.dumps({"format": 1, "synthetic": True}))
    for i in range(n):
        vad = rng.random(length) < 0.9
        if silent_from is not None:
            vad[silent_from:] = False
        write_item(folder / f"{i:05d}.npz", {
            "audio": (rng.standard_normal((mics, length)) * rng.uniform(0.2, 1.0, (mics, 1))).astype(np.float16),
            "scale": np.float64(1.0), "signal_power": np.float64(0.3), "vad": vad,
            "trajectory": rng.uniform(1, 3, (3, 3)), "array_position": np.array([2.0, 2.0, 1.0]),
            "snr_db": np.float64(rng.uniform(5, 30)), "t60": np.float64(0.5), "seed": np.int64(i)})
    return folder


@pytest.fixture
def caches(tmp_path):
    return make_cache(tmp_path / "train", 6, 1), make_cache(tmp_path / "val", 2, 2)


def tiny_recipe(**kw) -> Recipe:
    base = dict(name="tiny", epochs=2, trajectories_per_epoch=4, data="cache", cache_size=6, val_trajectories=2,
                phases=(Phase(0, (30.0, 30.0), 2, 1e-2), Phase(1, (5.0, 30.0), 4, 1e-3)))
    return Recipe(**{**base, **kw})


def make_trainer(out: Path, caches, recipe: Recipe | None = None, **kw) -> Trainer:
    opts = TrainOptions(tracker="tiny", out=out, recipe=recipe or tiny_recipe(), progress=False, **kw)
    return Trainer(opts, tracker=tiny_tracker(), feature_fn=energy_features, train_cache=caches[0],
                   val_cache=caches[1], log=lambda m: None)


def test_train_step_reduces_loss_on_a_fixed_batch(tmp_path, caches):
    trainer = make_trainer(tmp_path / "run", caches)
    items = CachedItems(TrajectoryCache(caches[0]), 6, 123, 0, 4, (30.0, 30.0), FS)
    batch = collate([items[k] for k in range(4)])
    losses = [trainer.train_step(batch) for _ in range(15)]
    assert losses[-1] < 0.8 * losses[0]


def test_resume_continues_exactly(tmp_path, caches):
    straight = make_trainer(tmp_path / "a", caches)
    straight.run()
    first = make_trainer(tmp_path / "b", caches, max_epochs=1)
    assert len(first.run()) == 1
    resumed = make_trainer(tmp_path / "b", caches, tiny_recipe(epochs=99), resume=True)  # keeps the run's 2
    history = resumed.run()
    assert [h["epoch"] for h in history] == [1, 2]
    for k, v in straight.network.state_dict().items():
        assert torch.equal(v, resumed.network.state_dict()[k]), k
    a = [h["val_loss"] for h in straight_history(tmp_path / "a")]
    assert a == [h["val_loss"] for h in history]
    assert (tmp_path / "b" / "log.csv").read_text().count("\n") == 3
    assert (tmp_path / "b" / "loss.png").stat().st_size > 1000


def straight_history(run: Path) -> list[dict]:
    from doabench.training.checkpoint import load_checkpoint

    return load_checkpoint(run / "checkpoint.safetensors")["history"]


def test_existing_run_needs_resume(tmp_path, caches):
    make_trainer(tmp_path / "a", caches, max_epochs=1).run()
    with pytest.raises(doabench.DoabenchError, match="--resume"):
        make_trainer(tmp_path / "a", caches)


def test_curriculum_switches_snr_batch_and_lr(tmp_path, caches):
    r = tiny_recipe()
    assert r.phase(0).snr == (30.0, 30.0) and r.phase(1).batch_size == 4 and r.phase(5).lr == 1e-3
    p = paper_recipe()
    assert (p.phase(19).snr, p.phase(19).batch_size, p.phase(19).lr) == ((30.0, 30.0), 5, 1e-4)
    assert (p.phase(20).snr, p.phase(20).batch_size, p.phase(20).lr) == ((5.0, 30.0), 10, 1e-5)
    assert (p.epochs, p.trajectories_per_epoch) == (80, 585)
    assert cpu_recipe().data == "cache"
    trainer = make_trainer(tmp_path / "run", caches)
    history = trainer.run()
    assert [(h["phase_snr"], h["batch_size"], h["lr"]) for h in history] == [("30-30", 2, 1e-2), ("5-30", 4, 1e-3)]
    assert trainer.optimizer.param_groups[0]["lr"] == 1e-3


def test_items_add_noise_at_the_phase_snr(caches):
    cache = TrajectoryCache(caches[0])
    items = CachedItems(cache, 6, 7, 0, 3, (20.0, 20.0), FS)
    rng = np.random.default_rng(episode_seed(7, 0, 1))
    clean = cache.load(int(rng.integers(6)))["audio"].astype(np.float32)
    noise = items[1]["audio"].numpy() - clean
    assert 10 * np.log10(0.3 / np.mean(noise**2)) == pytest.approx(20.0, abs=0.1)
    assert torch.equal(items[1]["audio"], items[1]["audio"])  # seeded: the same item twice


def _fake_librispeech(root: Path, n_speakers: int) -> Path:
    subset = root / "train-clean-100"
    for s in range(n_speakers):
        chapter = subset / str(100 + s) / str(1000 + s)
        chapter.mkdir(parents=True)
        (chapter / f"{100 + s}-{1000 + s}-0000.flac").touch()
    return root


def test_validation_speakers_never_train(tmp_path):
    from doabench.training.splits import SplitLibriSpeechSource, validation_speakers

    root = _fake_librispeech(tmp_path, 40)
    train = SplitLibriSpeechSource(root, "train-clean-100", "train")
    val = SplitLibriSpeechSource(root, "train-clean-100", "val")
    assert len(val.speakers) == 4 and not train.speakers & val.speakers
    assert train.speakers | val.speakers == {str(100 + s) for s in range(40)}
    assert val.speakers == validation_speakers(train.speakers | val.speakers)  # deterministic
    assert {s for s, _ in train.chapters}.isdisjoint(val.speakers)


def test_cli_rejects_unknown_and_non_learned_trackers(capsys, tmp_path):
    from doabench.cli.main import main

    for tracker, needle in (("no-such-tracker", "unknown tracker"), ("srp-max", "not a learned tracker")):
        assert main(["train", "--tracker", tracker, "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err and "Traceback" not in err


def test_lr_option_sets_each_phase_and_bad_values_are_one_line_errors(capsys, tmp_path):
    from doabench.cli.main import build_parser, main
    from doabench.cli.train import build_recipe

    def recipe(*extra):
        return build_recipe(build_parser().parse_args(["train", "--tracker", "spec-cnn2d", "--out", "r", *extra]))

    assert [p.lr for p in recipe().phases] == [1e-4, 1e-5]  # the paper's
    assert [p.lr for p in recipe("--lr", "1e-3,1e-4").phases] == [1e-3, 1e-4]
    one = recipe("--lr", "3e-4", "--switch-epoch", "9")
    assert [(p.start_epoch, p.lr) for p in one.phases] == [(0, 3e-4), (9, 3e-4)]
    for bad in ("fast", "1e-3,1e-4,1e-5", "0", "-1e-4,1e-5", "inf"):
        assert main(["train", "--tracker", "spec-cnn2d", "--tracker-opt", "weights=random", f"--lr={bad}",
                     "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err.strip()
        assert "--lr" in err and "\n" not in err and "Traceback" not in err
        assert not (tmp_path / "r").exists()


def test_export_writes_weights_with_training_metadata(tmp_path, caches):
    from safetensors import safe_open

    from doabench.training.export import export_weights

    make_trainer(tmp_path / "run", caches, max_epochs=1).run()
    path = export_weights(tmp_path / "run", tmp_path / "w.safetensors", "best", tracker=tiny_tracker())
    with safe_open(str(path), "pt") as f:
        meta = json.loads(f.metadata()["doabench"])
    assert meta["training"]["epochs_completed"] == 1 and meta["training"]["trajectories_seen"] == 4
    assert meta["doabench_version"] == doabench.__version__
    # which score chose the epoch, and the held score beside the raw ones
    assert meta["training"]["best_epoch_by"] == "val_rmsae_held"
    assert set(meta["training"]["validation"]) == {"val_loss", "val_rmsae_all", "val_rmsae_nonsilent", "val_rmsae_held"}


class MaxTracker(TinyTracker):
    """Reads the stored ``srp_max`` of 4x8 maps, like max-cnn1d."""

    def __init__(self, spec=None, **options):
        super().__init__(spec, **options)
        self.observation_spec = doabench.ObservationSpec.of(("srp_max",), (4, 8))
        self.network = TinyNet(2)

    def network_input(self, features):
        return features["srp_max"]  # (B, T, 2)


def test_training_from_a_dataset_file(tmp_path):
    from doabench.datasets import make_dataset

    (tmp_path / "t.toml").write_text(
        'id = "train-ds-test"\nversion = 0\nkind = "simulated"\nepisodes = 3\nbase_seed = 5\n[speech]\n'
        'corpus = "embedded"\n[scene]\nduration_s = 1.0\nn_points = 4\nt60 = [0.2, 0.3]\nroom_max = [5.0, 5.0, 3.0]\n')
    doabench.register_task(tmp_path / "t.toml")
    make_dataset("train-ds-test", tmp_path / "d.h5", features="srp:4x8", progress=False)
    val = make_cache(tmp_path / "val", 2, 3, mics=2, length=16000)
    frames = FrameSpec()

    def max_like(audio, vad):  # validation features of the right shape from the cached audio
        e = audio.unfold(-1, frames.window, frames.hop).pow(2).mean(-1).transpose(1, 2)  # (B, T, 2)
        return {"srp_max": e / (e.amax(-1, keepdim=True) + 1e-9)}

    opts = TrainOptions(tracker="max", out=tmp_path / "run", recipe=tiny_recipe(trajectories_per_epoch=3),
                        task="train-ds-test", progress=False, dataset=tmp_path / "d.h5")
    torch.manual_seed(0)
    history = Trainer(opts, tracker=MaxTracker(), feature_fn=max_like, val_cache=val, log=lambda m: None).run()
    assert [h["trajectories_seen"] for h in history] == [3, 6]
    assert all(np.isfinite(h["train_loss"]) for h in history)


def test_a_truncated_cache_item_is_a_one_line_error(tmp_path, caches):
    import shutil

    folder = tmp_path / "cache"
    shutil.copytree(caches[0], folder)
    path = folder / "00000.npz" if (folder / "00000.npz").exists() else sorted(folder.glob("*.npz"))[0]
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(doabench.DoabenchError, match="damaged"):
        TrajectoryCache(folder).load(int(path.stem))


def test_a_checkpoint_missing_keys_or_with_code_is_refused(tmp_path, caches):
    import pickle

    from doabench.training import checkpoint as ckpt

    make_trainer(tmp_path / "a", caches, max_epochs=1).run()
    state = ckpt.load_checkpoint(tmp_path / "a" / ckpt.LATEST)
    assert state["epoch"] == 1 and state["best_epoch"] == 1
    del state["history"]
    ckpt.save_checkpoint(tmp_path / "b.safetensors", state)
    with pytest.raises(doabench.DoabenchError, match="missing history"):
        ckpt.load_checkpoint(tmp_path / "b.safetensors")

    class Boom:
        def __reduce__(self):
            return (exec, ("open(%r, 'w').write('ran')" % str(tmp_path / "ran.txt"),))

    (tmp_path / "evil.safetensors").write_bytes(pickle.dumps({"format": 2, "x": Boom()}))
    with pytest.raises(doabench.DoabenchError):
        ckpt.load_checkpoint(tmp_path / "evil.safetensors")
    assert not (tmp_path / "ran.txt").exists()


def test_cpu_preset_without_a_cache_leaves_no_run_folder(tmp_path, capsys):
    from doabench.cli.main import main as cli

    out = tmp_path / "runs" / "x"
    rc = cli(["train", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=random", "--preset", "cpu",
              "--cache-root", str(tmp_path / "nocache"), "--out", str(out), "--quiet"])
    assert rc == 2 and "--build-cache" in capsys.readouterr().err
    assert not out.exists()


def test_compact_checkpoint_stores_moments_in_eight_bits_and_resumes(tmp_path):
    """A compact run state (for committing): latest weights exact, Adam moments in 8 bits a value on a
    per-block log scale (within 7 % of each value), best weights as an 8-bit difference from the
    latest; the optimiser loads it and keeps training."""
    import random

    from doabench.training import checkpoint as ckpt

    torch.manual_seed(0)
    net = torch.nn.Linear(256, 64)
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    for _ in range(3):
        opt.zero_grad()
        net(torch.randn(8, 256)).square().mean().backward()
        opt.step()
    best = {k: v + 0.01 * torch.randn_like(v) for k, v in net.state_dict().items()}
    state = {"epoch": 3, "model": net.state_dict(), "best_model": best, "best_epoch": 2, "optimizer": opt.state_dict(),
             "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
             "recipe": {}, "tracker": "t", "task": "sim-train", "history": [], "best": 1.0, "compute_s": 1.0,
             "trajectories_seen": 3}
    path = tmp_path / ckpt.LATEST
    ckpt.save_checkpoint(path, state)
    before, after = ckpt.compact_checkpoint(path)
    assert after < 0.5 * before  # 7 of 16 bytes a parameter, and the per-block scales
    loaded = ckpt.load_checkpoint(path)
    assert loaded["compact"] == "log8" and loaded["epoch"] == 3
    assert all(torch.equal(loaded["model"][k], v) for k, v in net.state_dict().items())  # exact
    for index, per_param in opt.state_dict()["state"].items():
        for key in ("exp_avg", "exp_avg_sq"):
            exact, decoded = per_param[key], loaded["optimizer"]["state"][index][key]
            assert decoded.shape == exact.shape and decoded.dtype == torch.float32
            assert torch.equal(torch.sign(decoded), torch.sign(exact))
            assert torch.all((decoded - exact).abs() <= 0.07 * exact.abs() + 1e-7 * exact.abs().max())
    for k, v in loaded["best_model"].items():
        assert (v - best[k]).abs().max() <= (best[k] - net.state_dict()[k]).abs().max() / 254 + 1e-7
    net2 = torch.nn.Linear(256, 64)
    net2.load_state_dict(loaded["model"])
    opt2 = torch.optim.Adam(net2.parameters(), 1e-3)
    opt2.load_state_dict(loaded["optimizer"])
    assert all(v.dtype == torch.float32 for p in opt2.state.values() for k, v in p.items() if k != "step")
    opt2.zero_grad()
    net2(torch.randn(8, 256)).square().mean().backward()
    opt2.step()
    assert all(torch.isfinite(p).all() for p in net2.parameters())


def test_resume_from_a_compact_state_continues_closely(tmp_path, caches):
    """Committed (compact) run states resume: the next epoch runs from the 8-bit moments and ends
    close to the uninterrupted run."""
    from doabench.training import checkpoint as ckpt

    straight = make_trainer(tmp_path / "a", caches)
    straight.run()
    make_trainer(tmp_path / "b", caches, max_epochs=1).run()
    ckpt.compact_checkpoint(tmp_path / "b" / ckpt.LATEST)
    resumed = make_trainer(tmp_path / "b", caches, tiny_recipe(epochs=99), resume=True)
    history = resumed.run()
    assert [h["epoch"] for h in history] == [1, 2]
    for k, v in straight.network.state_dict().items():
        assert torch.allclose(v, resumed.network.state_dict()[k], rtol=1e-2, atol=1e-4), k
    state = ckpt.load_checkpoint(tmp_path / "b" / ckpt.LATEST)  # written by the trainer again: float32
    assert not state.get("compact") and all(
        v.dtype == torch.float32 for p in state["optimizer"]["state"].values() for v in p.values())


class TrainedTinyTracker(TinyTracker):
    """A tiny tracker that says it loaded trained weights (a fine-tuning start)."""

    trained = True

    def describe(self):
        d = super().describe()
        d.update(weights="/somewhere/tiny.safetensors", weights_hash="ab" * 32,
                 training={"trajectories_seen": 100, "compute_s": 50.0})
        return d


def test_a_run_from_trained_weights_records_its_start_and_the_export_its_totals(tmp_path, caches):
    from safetensors import safe_open

    from doabench.training.checkpoint import load_checkpoint
    from doabench.training.export import export_weights

    opts = TrainOptions(tracker="tiny", out=tmp_path / "run", recipe=tiny_recipe(), progress=False, max_epochs=1)
    torch.manual_seed(0)
    logged: list[str] = []
    Trainer(opts, tracker=TrainedTinyTracker(), feature_fn=energy_features, train_cache=caches[0],
            val_cache=caches[1], log=logged.append).run()
    start = load_checkpoint(tmp_path / "run" / "checkpoint.safetensors")["initial_weights"]
    assert start["weights"] == "tiny.safetensors" and start["sha256"] == "ab" * 32
    assert start["validation"]["val_rmsae_all"] > 0 and any(m.startswith("starting weights") for m in logged)
    path = export_weights(tmp_path / "run", tmp_path / "w.safetensors", "latest", tracker=tiny_tracker())
    with safe_open(str(path), "pt") as f:
        training = json.loads(f.metadata()["doabench"])["training"]
    assert training["fine_tuned_from"]["sha256"] == "ab" * 32
    assert training["trajectories_seen"] == 4 and training["trajectories_seen_total"] == 104
    assert training["compute_s_total"] == pytest.approx(50.0 + training["compute_s"], abs=0.11)
    # a run from scratch records no start
    make_trainer(tmp_path / "scratch", caches, max_epochs=1).run()
    assert load_checkpoint(tmp_path / "scratch" / "checkpoint.safetensors")["initial_weights"] is None


def test_resume_refuses_recipe_options_that_differ_from_the_run(tmp_path, caches):
    from doabench.cli.main import build_parser
    from doabench.cli.train import build_recipe, given_recipe_options

    make_trainer(tmp_path / "run", caches, max_epochs=1).run()
    faster = tiny_recipe(phases=(Phase(0, (30.0, 30.0), 2, 1e-1), Phase(1, (5.0, 30.0), 4, 1e-3)))
    with pytest.raises(doabench.DoabenchError, match=r"--lr 0.1,0.001 \(the run's: 0.01,0.001\)"):
        make_trainer(tmp_path / "run", caches, faster, resume=True, recipe_options=("--lr",))
    # a switch may move only while neither it nor the asked one lies in the epochs trained (1 here)
    later = tiny_recipe(phases=(Phase(0, (30.0, 30.0), 2, 1e-2), Phase(2, (5.0, 30.0), 4, 1e-3)))
    moved = make_trainer(tmp_path / "run", caches, later, resume=True, recipe_options=("--switch-epoch", "--seed"))
    assert [p.start_epoch for p in moved.recipe.phases] == [0, 2]
    make_trainer(tmp_path / "run", caches, resume=True, max_epochs=2).run()  # now past the switch
    with pytest.raises(doabench.DoabenchError, match=r"--switch-epoch 2 \(the run's: 1\)"):
        make_trainer(tmp_path / "run", caches, later, resume=True, recipe_options=("--switch-epoch",))
    # options that agree with the run, and options not given, let it resume with its own recipe
    same = make_trainer(tmp_path / "run", caches, faster, resume=True, recipe_options=("--switch-epoch", "--seed"))
    assert [p.lr for p in same.recipe.phases] == [1e-2, 1e-3]
    # the CLI passes exactly the recipe options the user typed
    args = build_parser().parse_args(["train", "--tracker", "spec-cnn2d", "--out", "r", "--lr", "1e-3", "--resume"])
    assert given_recipe_options(args) == ("--lr",)
    assert build_recipe(args).name == "paper" and build_recipe(args).seed == 0
    args = build_parser().parse_args(["train", "--tracker", "spec-cnn2d", "--out", "r", "--preset", "cpu",
                                      "--seed", "3", "--epoch-size", "7"])
    assert given_recipe_options(args) == ("--preset", "--seed", "--epoch-size")


def test_resume_refuses_another_task_or_a_network_that_does_not_fit(tmp_path, caches):
    make_trainer(tmp_path / "run", caches, max_epochs=1).run()
    with pytest.raises(doabench.DoabenchError, match="trained on task sim-train, not sim-grid"):
        make_trainer(tmp_path / "run", caches, resume=True, task="sim-grid")

    wider = TinyTracker()
    wider.network = TinyNet(channels=M + 1)
    opts = TrainOptions(tracker="tiny-wide", out=tmp_path / "run", recipe=tiny_recipe(), progress=False, resume=True)
    with pytest.raises(doabench.DoabenchError, match="holds a run of tiny whose weights do not fit tiny-wide"):
        Trainer(opts, tracker=wider, feature_fn=energy_features, train_cache=caches[0], val_cache=caches[1],
                log=lambda m: None)


def test_resume_and_export_refuse_a_tracker_that_reads_other_observations(tmp_path, caches):
    """A tracker option may change what the network reads and not its shapes (a spectrogram
    tracker's phase): the run records its observations and options, a resume or an export with a
    tracker reading anything else is refused in one line, naming the options it started with."""
    from doabench.training import checkpoint as ckpt
    from doabench.training.export import export_weights

    make_trainer(tmp_path / "run", caches, max_epochs=1, tracker_options={"weights": "random", "gain": 2}).run()
    state = ckpt.load_checkpoint(tmp_path / "run" / ckpt.LATEST)
    assert state["tracker_options"] == {"gain": 2}  # what builds the same tracker again, weights aside
    assert state["observations"] == tiny_tracker().observation_spec.to_dict()
    other = tiny_tracker()
    other.observation_spec = doabench.ObservationSpec.of(("energy",), frame_spec=doabench.FrameSpec(1024, 512))
    opts = TrainOptions(tracker="tiny", out=tmp_path / "run", recipe=tiny_recipe(), progress=False, resume=True)
    with pytest.raises(doabench.DoabenchError, match="holds a run trained on energy @ 256/192.*not on energy @ "
                                                     "1024/512.*--tracker-opt gain=2"):
        Trainer(opts, tracker=other, feature_fn=energy_features, train_cache=caches[0], val_cache=caches[1],
                log=lambda m: None)
    with pytest.raises(doabench.DoabenchError, match="does not read"):
        export_weights(tmp_path / "run", tmp_path / "w.safetensors", tracker=other)
    assert not (tmp_path / "w.safetensors").exists()


def test_resume_refuses_a_run_of_another_task_version(tmp_path, caches):
    from doabench.training import checkpoint as ckpt

    make_trainer(tmp_path / "run", caches, max_epochs=1).run()
    path = tmp_path / "run" / ckpt.LATEST
    state = ckpt.load_checkpoint(path)
    assert state["task_version"] == doabench.get_task_spec("sim-train").version
    make_trainer(tmp_path / "run", caches, resume=True, max_epochs=0)  # same version: resumes
    state["task_version"] = 99
    ckpt.save_checkpoint(path, state)
    with pytest.raises(doabench.DoabenchError, match="version 99"):
        make_trainer(tmp_path / "run", caches, resume=True)


def test_finetune_preset_is_the_papers_second_phase_at_a_gentler_start():
    from doabench.training.recipes import get_recipe, paper_recipe

    ft, paper = get_recipe("finetune"), paper_recipe()
    assert ft.data == "simulate" and ft.trajectories_per_epoch == paper.trajectories_per_epoch
    assert [(p.snr, p.batch_size) for p in ft.phases] == [(paper.phases[1].snr, paper.phases[1].batch_size)] * 2
    assert [p.lr for p in ft.phases] == [3e-5, paper.phases[1].lr]


def test_validation_scores_the_hold_rule_and_new_runs_select_by_it(tmp_path, caches):
    from doabench.training import checkpoint as ckpt

    caches = (caches[0], make_cache(tmp_path / "val-silent", 2, 3, silent_from=L // 3))
    trainer = make_trainer(tmp_path / "run", caches, max_epochs=1)
    trainer.hold_frames = 2  # the tiny tracker never holds; a learned causal one does
    val = trainer.prepare_validation()
    metrics = trainer.validate(val)
    # the same numbers by hand: raw outputs, then the outputs held with doabench.hold_in_silences
    raw, held = [], []
    with torch.no_grad():
        for x, truth, vad in val:
            y = trainer.forward(x, truth)
            for b in range(len(y)):
                d = y[b].numpy()
                for out, dirs in ((raw, d), (held, doabench.hold_in_silences(d, vad[b].numpy(), 2))):
                    cos = (dirs * truth[b].numpy()).sum(-1) / np.linalg.norm(dirs, axis=-1) / np.linalg.norm(truth[b].numpy(), axis=-1)
                    out.extend(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    assert metrics["val_rmsae_all"] == pytest.approx(np.sqrt(np.mean(np.square(raw))), rel=1e-4)
    assert metrics["val_rmsae_held"] == pytest.approx(np.sqrt(np.mean(np.square(held))), rel=1e-4)
    assert all(v[:, -3:].sum() == 0 for _, _, v in val)  # a long final silence, so the rule had work
    assert metrics["val_rmsae_held"] != pytest.approx(metrics["val_rmsae_all"], rel=1e-3)
    trainer.run()
    state = ckpt.load_checkpoint(tmp_path / "run" / ckpt.LATEST)
    assert state["best_by"] == "val_rmsae_held"
    assert state["best"] == state["history"][0]["val_rmsae_held"]
    assert "val_rmsae_held" in (tmp_path / "run" / "log.csv").read_text().splitlines()[0]
    # a state written before the held score existed keeps selecting by all frames when resumed
    del state["best_by"]
    ckpt.save_checkpoint(tmp_path / "run" / ckpt.LATEST, state)
    assert make_trainer(tmp_path / "run", caches, resume=True).best_by == "val_rmsae_all"


def test_held_frame_index_is_batched_and_matches_the_tracker_rule():
    from doabench.trackers import held_frame_index

    vad = np.array([[0, 1, 0, 0, 0, 1, 0, 0], [1, 0, 0, 0, 0, 0, 0, 0]], bool)
    index = held_frame_index(vad, 2)
    # frame 0 precedes any voice (kept); a frame is informed while voice lies within its last two
    # frames, and from the second silent frame on the last informed frame repeats
    assert index.tolist() == [[0, 1, 2, 2, 2, 5, 6, 6], [0, 1, 1, 1, 1, 1, 1, 1]]
    assert all(np.array_equal(held_frame_index(v, 2), i) for v, i in zip(vad, index))
    with pytest.raises(doabench.DoabenchError, match="hold must be >= 1"):
        held_frame_index(vad, 0)


def test_a_bf16_run_resumed_on_a_cpu_without_native_bf16_continues_in_fp32(tmp_path, caches, monkeypatch):
    """Emulated bf16 autocast is ~13x slower than float32 (AVX2-only CPU): auto falls back, says so,
    and the per-epoch record and the exported weights show both precisions."""
    import doabench.training.precision as precision_module
    from doabench.training.export import precision_record

    make_trainer(tmp_path / "run", caches, max_epochs=1, precision="bf16").run()
    monkeypatch.setattr(precision_module, "cpu_has_native_bf16", lambda: False)
    notes: list[str] = []
    opts = TrainOptions(tracker="tiny", out=tmp_path / "run", recipe=tiny_recipe(), progress=False, resume=True)
    resumed = Trainer(opts, tracker=tiny_tracker(), feature_fn=energy_features, train_cache=caches[0],
                      val_cache=caches[1], log=notes.append)
    assert resumed.precision == "fp32"
    assert any("no native bf16" in n and "continues in fp32" in n for n in notes)
    resumed.run()
    from doabench.training.checkpoint import load_checkpoint

    state = load_checkpoint(tmp_path / "run" / "checkpoint.safetensors")
    assert [h["precision"] for h in state["history"]] == ["bf16", "fp32"]
    assert precision_record(state) == "bf16 (epoch 1), fp32 (epoch 2)"


def test_resume_precision_keeps_the_run_unless_told_or_unsupported(monkeypatch):
    import doabench.training.precision as precision_module
    from doabench.training.precision import resume_precision

    cpu = torch.device("cpu")
    monkeypatch.setattr(precision_module, "cpu_has_native_bf16", lambda: True)
    assert resume_precision("bf16", "auto", cpu) == ("bf16", None)
    assert resume_precision("fp32", "auto", cpu) == ("fp32", None)  # auto does not upgrade an fp32 run
    # a bf16 run that went on in fp32 on an AVX2-only CPU goes back to bf16 where bf16 is native
    precision, note = resume_precision("fp32", "auto", cpu, started_in="bf16")
    assert precision == "bf16" and "continues in bf16" in note
    assert resume_precision("fp32", "auto", cpu, started_in="fp32") == ("fp32", None)
    assert resume_precision(None, "auto", cpu) == ("bf16", None)
    precision, note = resume_precision("bf16", "fp32", cpu)
    assert precision == "fp32" and "--precision" in note
    monkeypatch.setattr(precision_module, "cpu_has_native_bf16", lambda: False)
    assert resume_precision(None, "auto", cpu) == ("fp32", None)
    assert resume_precision("bf16", "bf16", cpu) == ("bf16", None)  # forced: kept, however slow
    assert resume_precision("bf16", "auto", cpu)[0] == "fp32"
    assert resume_precision("fp32", "auto", cpu, started_in="bf16") == ("fp32", None)  # still no native bf16
    with pytest.raises(doabench.DoabenchError, match="precision"):
        resume_precision("bf16", "fp16", cpu)


def test_run_progress_fills_in_what_older_states_lack_and_keeps_the_best_weights(tmp_path):
    from doabench.training.run_state import LEGACY_BEST_BY, RunProgress, best_by, check_same_task

    old = {"epoch": 2, "history": [{"epoch": 1}, {"epoch": 2, "precision": "fp32"}], "best": 5.0, "compute_s": 9.0,
           "trajectories_seen": 8, "precision": "bf16", "task": "sim-train"}
    progress = RunProgress.from_saved(old)
    assert [r["precision"] for r in progress.history] == ["bf16", "fp32"]  # rows before the per-epoch record
    assert progress.best_epoch == 2 and progress.latest_is_best
    assert best_by(old) == LEGACY_BEST_BY and best_by(None) == "val_rmsae_held"
    # the task version of a state that did not record it comes from the run's config.json
    (tmp_path / "config.json").write_text(json.dumps({"task_version": 99}))
    with pytest.raises(doabench.DoabenchError, match="version 99"):
        check_same_task(old, doabench.get_task_spec("sim-train"), tmp_path)
    # a worse epoch keeps the weights it started from as the best; a better one drops them again
    before = {"w": torch.zeros(1)}
    progress.add_epoch({"epoch": 3}, 6.0, before)
    assert (progress.epoch, progress.best_epoch, progress.best_weights) == (3, 2, before)
    progress.add_epoch({"epoch": 4}, 4.0, None)
    assert (progress.best, progress.best_epoch, progress.best_weights) == (4.0, 4, None)


def test_the_trainer_module_keeps_the_names_other_code_imports():
    import doabench.training.trainer as trainer_module

    for name in ("Trainer", "TrainOptions", "cpu_has_native_bf16", "default_workers", "available_cores", "write_log",
                 "plot_history", "LOCK_NAME", "CSV_COLUMNS", "resume_precision"):
        assert hasattr(trainer_module, name), name


def test_the_frame_difference_loss_trains_is_recorded_and_a_resume_must_agree(tmp_path, caches, capsys):
    from doabench.cli.main import build_parser, main
    from doabench.cli.train import build_recipe

    trainer = make_trainer(tmp_path / "run", caches, tiny_recipe(delta_loss=2.0), max_epochs=1)
    items = CachedItems(TrajectoryCache(caches[0]), 6, 123, 0, 4, (30.0, 30.0), FS)
    batch = collate([items[k] for k in range(4)])
    with torch.no_grad():
        x = trainer.network_input(batch)
        y = trainer.forward(x, batch["truth"])
    from doabench.training.losses import tracking_loss
    expected = float(tracking_loss(y, batch["truth"], 2.0))
    assert trainer.train_step(batch) == pytest.approx(expected, rel=1e-5)
    assert expected > float(torch.nn.functional.mse_loss(y, batch["truth"]))
    trainer.run()
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["recipe"]["delta_loss"] == 2.0
    with pytest.raises(doabench.DoabenchError, match=r"--delta-loss 0.5 \(the run's: 2.0\)"):
        make_trainer(tmp_path / "run", caches, tiny_recipe(delta_loss=0.5), resume=True, recipe_options=("--delta-loss",))
    args = build_parser().parse_args(["train", "--tracker", "spec-cnn2d", "--out", "r", "--delta-loss", "0.5"])
    assert build_recipe(args).delta_loss == 0.5
    assert build_recipe(build_parser().parse_args(["train", "--tracker", "spec-cnn2d", "--out", "r"])).delta_loss == 0
    for bad in ("-1", "nan", "inf"):
        assert main(["train", "--tracker", "spec-cnn2d", "--tracker-opt", "weights=random", f"--delta-loss={bad}",
                     "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err.strip()
        assert "--delta-loss" in err and "\n" not in err and "Traceback" not in err
        assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("source, options, message", [
    ("seldnet", [], "needs weights of 'cross3d'"),
    ("cross3d:16x32", ["weights=random"], "no trained weights"),
    ("cross3d:8x16", ["weights=paper"], "pooling blocks"),
])
def test_a_warm_start_from_other_weights_is_refused_before_training(tmp_path, capsys, source, options, message):
    from doabench.cli.main import main as cli

    out = tmp_path / "run"
    args = ["train", "--tracker", "cross3d:32x64", "--warm-start", source, "--out", str(out), "--quiet"]
    for option in options:
        args += ["--warm-start-opt", option]
    assert cli(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_training_on_a_benchmark_tasks_dataset_is_warned_about(tmp_path, monkeypatch, capsys):
    """``train --dataset`` says in one line that a dataset of a benchmark task (one that scores
    trackers) makes the model's scores there meaningless; a training task's dataset is not warned about."""
    import h5py

    from doabench.cli.main import main
    from doabench.datasets import make_dataset
    from doabench.training import trainer as trainer_module

    class NoTraining:  # what happens after the warning is not this test's business
        def __init__(self, options, log=print):
            pass

        def stop_note(self):
            return ""

        def run(self):
            return []

    monkeypatch.setattr(trainer_module, "Trainer", NoTraining)
    (tmp_path / "t.toml").write_text(
        'id = "bench-ds-test"\nversion = 0\nkind = "simulated"\nepisodes = 1\nbase_seed = 6\n[speech]\n'
        'corpus = "embedded"\n[scene]\nduration_s = 1.0\nn_points = 4\nt60 = [0.2, 0.3]\nroom_max = [5.0, 5.0, 3.0]\n')
    doabench.register_task(tmp_path / "t.toml")
    bench = tmp_path / "bench.h5"
    make_dataset("bench-ds-test", bench, features="srp:4x8", progress=False)
    argv = ["train", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=random", "--out", str(tmp_path / "run"),
            "--no-compile", "--quiet", "--dataset"]
    capsys.readouterr()
    assert main([*argv, str(bench)]) == 0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"doabench train: warning: {bench} holds episodes of bench-ds-test, "
                                              "a benchmark task"), err
    assert "makes this model's scores on bench-ds-test meaningless" in err
    training = tmp_path / "training.h5"
    training.write_bytes(bench.read_bytes())
    with h5py.File(training, "r+") as f:  # the same file as a training task's (train-clean-100 speech)
        spec = json.loads(f.attrs["task_spec"])
        spec["id"], spec["params"]["speech"] = "sim-train", {"corpus": "librispeech", "subset": "train-clean-100"}
        f.attrs["task_spec"] = json.dumps(spec)
    assert main([*argv, str(training)]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_validation_cache_says_where_and_how_big_before_it_is_built(tmp_path):
    from doabench.training.pipeline import ensure_cache

    (tmp_path / "t.toml").write_text(
        'id = "valcache-test"\nversion = 0\nkind = "simulated"\nepisodes = 1\nbase_seed = 8\n[speech]\n'
        'corpus = "embedded"\n[scene]\nduration_s = 1.0\nn_points = 4\nt60 = [0.2, 0.3]\nroom_max = [5.0, 5.0, 3.0]\n')
    doabench.register_task(tmp_path / "t.toml")
    spec = doabench.get_task_spec("valcache-test")
    recipe = paper_recipe().replace(duration_s=1.0)
    logged: list[tuple[str, int]] = []  # each line with the number of items cached when it was said

    def log(line: str) -> None:
        logged.append((line, len(list((tmp_path / "cache").rglob("*.npz")))))

    folder = ensure_cache(tmp_path / "cache", spec, recipe, "val", 2, None, "builtin", log)
    first, cached = logged[0]
    assert cached == 0 and first.startswith(f"building the validation cache in {folder}: 2 trajectories of 1 s"), first
    import re

    sizes = sum(p.stat().st_size for p in folder.glob("*.npz"))
    said = re.search(r"about ([0-9.]+) MB on disk", first)
    assert said is not None and abs(float(said.group(1)) * 1e6 / sizes - 1) < 0.05, (first, sizes)
    logged.clear()
    ensure_cache(tmp_path / "cache", spec, recipe, "val", 3, None, "builtin", log)
    assert logged[0][0].startswith(f"building the validation cache in {folder}: 1 of 3 trajectories"), logged
