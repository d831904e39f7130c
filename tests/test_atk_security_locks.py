"""Found by atk_security: what two processes share is locked, and paths a file names stay inside
its folder.

``claims`` held its study folder's lock but not the lock of each run folder it trained
(``OUT/runs/NAME/seed-S``), which ``fit`` takes (``RUN_DIR/.sc3d.lock``): a ``sc3d-train fit
--config OUT/runs/NAME/seed-0/config.yaml --out OUT/runs/NAME/seed-0`` (or ``fit --resume`` there)
started while the study trained that run was not refused: it replaced the run's config.yaml,
metrics.csv and checkpoints under the study, exit 0."""
from __future__ import annotations

import pytest


def test_claims_holds_the_lock_of_the_run_folder_it_trains(sample_shards, tmp_path, monkeypatch):
    from sc3d_data.io.outlock import LockError, exclusive_lock
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all
    from sc3d_train.loop import trainer

    real_fit, seen = trainer.fit, []

    def fit_beside_another(cfg, *args, **kwargs):
        with pytest.raises(LockError, match="sc3d-train claims"):  # what `sc3d-train fit --out RUN` meets
            with exclusive_lock(cfg.out, "sc3d-train fit", create=True):
                pass
        seen.append(cfg.out)
        return real_fit(cfg, *args, **kwargs)

    monkeypatch.setattr(trainer, "fit", fit_beside_another)
    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0})
    run_all(sample_shards, sample_shards, tmp_path / "study", preset, eval_split="test", device="cpu",
            runs=["sup-3tube"], echo=lambda line: None)
    assert len(seen) == 1


def test_an_index_whose_object_source_is_no_text_is_no_traceback(tmp_path):
    """``front_axis.auto_fronts`` (846e95f) read each object's ``source`` of ``index.json`` and gave
    it to ``resolve_front``: a hand-edited or foreign index whose ``source`` was a number or null
    (an import's objects have none) stopped ``eval``, ``fit --resume`` and ``fit --config`` of
    shards rendered with an explicit ``--front`` with ``TypeError: expected str, bytes or
    os.PathLike object, not int``. Such a source gives no ``auto`` front: the front stays as given."""
    import json

    from sc3d_train.loop.front_axis import auto_fronts, front_as_auto

    for bad in (5, None, ["a.glb"], {"x": 1}):
        (tmp_path / "index.json").write_text(json.dumps({"objects": [{"source": "/m/car/a.glb"}, {"source": bad}]}))
        assert auto_fronts(tmp_path) == set()
        assert front_as_auto({"front": "+Z"}, tmp_path) == {"front": "+Z"}
