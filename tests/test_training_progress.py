"""The training progress bar counts batches as they finish: whenever it shows a loss, it shows the
number of batches that loss came from (it used to sit at 0/N while the loss moved)."""
from __future__ import annotations

import io
import re

from doabench.training.progress import EpochProgress, loader_length


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _drawn(text: str) -> list[tuple[int, int, str | None]]:
    """(count, total, loss) of every state of the bar written to ``text``."""
    out = []
    for frame in re.split(r"[\r\n]", text):
        m = re.search(r"\| ?(\d+)/(\d+) \[", frame)  # the count after the bar, not the "epoch 1/2" label
        if m:
            loss = re.search(r"loss=([0-9.]+)", frame)
            out.append((int(m.group(1)), int(m.group(2)), loss.group(1) if loss else None))
    return out


def test_every_drawn_loss_comes_with_its_batch_count() -> None:
    stream = _Terminal()
    with EpochProgress(5, "epoch 1/1", file=stream, mininterval=0.0) as bar:
        for k in range(1, 6):
            bar.step(float(k))  # the loss after batch k is k: the count drawn with it must be k
            assert bar.n == k and bar.bar.n == k
    states = [s for s in _drawn(stream.getvalue()) if s[2] is not None]
    assert states, stream.getvalue()
    assert all(count == int(float(loss)) and total == 5 for count, total, loss in states), states
    assert states[-1][:2] == (5, 5)


def test_a_log_file_gets_the_count_too() -> None:
    """Written to a file (not a terminal) the bar redraws rarely; when it does (at the end at
    least), the count is the batches done, not 0."""
    stream = io.StringIO()
    bar = EpochProgress(3, "epoch 1/1", file=stream)
    for _ in range(3):
        bar.step(0.5)
    assert bar.bar.n == 3
    bar.close()
    assert _drawn(stream.getvalue())[-1] == (3, 3, "0.5000")


def test_disabled_bar_writes_nothing_and_lengthless_loaders_count_without_total() -> None:
    stream = io.StringIO()
    bar = EpochProgress(3, "x", enabled=False, file=stream)
    bar.step(1.0)
    bar.close()
    assert stream.getvalue() == "" and bar.n == 1
    assert loader_length(iter([1, 2])) is None and loader_length([1, 2, 3]) == 3


def test_the_trainer_advances_the_bar_batch_by_batch(tmp_path, monkeypatch) -> None:
    import doabench.training.trainer as trainer_module
    from test_training import make_cache, make_trainer, use_energy_kind

    use_energy_kind(monkeypatch)

    caches = make_cache(tmp_path / "train", 6, 1), make_cache(tmp_path / "val", 2, 2)

    streams = []

    class Recorded(EpochProgress):
        def __init__(self, total, desc, enabled=True, file=None, mininterval=None):
            streams.append(_Terminal())
            super().__init__(total, desc, True, streams[-1], 0.0)

    monkeypatch.setattr(trainer_module, "EpochProgress", Recorded)
    trainer = make_trainer(tmp_path / "run", caches, max_epochs=1)
    trainer.run()
    (stream,) = streams  # one epoch, one bar
    states = [s for s in _drawn(stream.getvalue()) if s[2] is not None]
    total = states[0][1]
    counts = list(dict.fromkeys(s[0] for s in states))  # the closing redraw repeats the last state
    assert total >= 2 and counts == list(range(1, total + 1)), states
