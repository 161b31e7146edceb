"""stable-baselines3 callbacks used by :mod:`agents.rl.training`.

- :class:`EstimationMetricsCallback`: averages the env's per-step ``info`` metrics
  (``est_*``, ``track_*``, ``reward_*``) and the end-of-episode summaries (``episode_*``) into
  the SB3 logger (TensorBoard/CSV), ignoring NaN, plus failure rates by termination reason.
- :class:`TqdmProgressCallback`: a plain ``tqdm`` progress bar (SB3's own
  ``ProgressBarCallback`` needs ``rich``, which is not a dependency).
- :class:`SaveVecNormalizeCallback`: saves the ``VecNormalize`` statistics (pickle and
  arrays) next to ``EvalCallback``'s ``best_model.zip`` so the best model can be evaluated like
  the final one.
- :class:`StopWhenSet`: ends ``learn`` at the next step once an event is set (a SIGTERM
  asked for it, :func:`agents.io.signals.sigterm_as_request`).
- :class:`AtomicCheckpointCallback`, :class:`AtomicEvalCallback`: SB3's checkpoint and
  evaluation callbacks with every file written atomically (SB3 writes in place, so a kill or a
  full disk during a save left a truncated checkpoint, ``best_model.zip`` or
  ``evaluations.npz``, which ``--resume`` and the learning curve then failed on), and each
  saved model's weights and statistics also as arrays (:mod:`agents.rl.saved.safe_files`).
"""

from __future__ import annotations

import math
import re
import shutil
import sys
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from tqdm import tqdm

from agents.io.outputs import atomic_produce, atomic_produce_all, commit
from agents.rl.saved.safe_files import Normalization, save_files, write_normalization, write_policy

STEP_PREFIXES = ("est_", "track_", "reward_")
EPISODE_PREFIX = "episode_"


def _finite_float(value: object) -> float | None:
    """``float(value)`` for finite real scalars, else ``None`` (bools, arrays, strings, NaN)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        return None
    out = float(value)
    return out if math.isfinite(out) else None


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_").lower() or "unknown"


class EstimationMetricsCallback(BaseCallback):
    """Log the env's estimation/tracking metrics into the SB3 logger (TensorBoard/CSV).

    Each finite numeric ``info`` entry whose key starts with one of ``prefixes`` is averaged
    under ``quadslam/<key>``; the episode summaries the env adds on the last step
    (``episode_*``) under ``quadslam_episode/<key>``. At each episode end
    ``quadslam_episode/failure_rate`` averages ``terminated`` (any termination reason) and
    ``quadslam_episode/n_<reason>`` counts episodes per reason since the start of training.
    Means are over all steps and lanes since the last log dump (NaN entries skipped).

    With :class:`agents.rl.vec_adapter.QuadSLAMVecEnv` (found through the ``VecEnv`` wrappers)
    the terms are read from its ``step_info`` arrays, so the cost per step does not grow with
    the number of lanes; with any other ``VecEnv`` from the per-lane ``infos``. The sums are
    merged into the logger's running means at the end of each rollout.

    Args:
        prefixes: Key prefixes of the per-step metrics.
        keys: Explicit per-step keys instead of prefix matching (e.g. ``["est_pos_err_m"]``).
        verbose: SB3 verbosity.
    """

    def __init__(
        self,
        prefixes: Sequence[str] = STEP_PREFIXES,
        keys: Sequence[str] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        self.prefixes = tuple(prefixes)
        self.keys = None if keys is None else tuple(keys)
        self.reasons: Counter[str] = Counter()
        self._route: dict[str, str | None] = {}
        self._sums: dict[str, float] = defaultdict(float)
        self._counts: dict[str, int] = defaultdict(int)

    def _log_name(self, key: str) -> str | None:
        """Logger key for an ``info`` key, or ``None`` if it is not logged."""
        name = self._route.get(key, "")
        if name == "":
            if key.startswith(EPISODE_PREFIX):
                name = f"quadslam_episode/{key[len(EPISODE_PREFIX) :]}"
            elif key in self.keys if self.keys is not None else key.startswith(self.prefixes):
                name = f"quadslam/{key}"
            else:
                name = None
            self._route[key] = name
        return name

    def _step_arrays(self) -> dict[str, np.ndarray] | None:
        """The adapter's ``step_info`` arrays, or ``None`` for another ``VecEnv``."""
        env: Any = self.training_env
        while env is not None and not hasattr(env, "step_info"):
            env = getattr(env, "venv", None)
        return None if env is None else env.step_info

    def _add(self, name: str, values: np.ndarray) -> None:
        finite = np.isfinite(values)
        n = int(finite.sum())
        if n:
            self._sums[name] += float(values[finite].sum())
            self._counts[name] += n

    def _on_step(self) -> bool:
        infos = self.locals.get("infos") or ()
        dones = self.locals.get("dones")
        arrays = self._step_arrays()
        if arrays is not None:
            for key, values in arrays.items():
                name = self._log_name(key)
                if name is not None:
                    self._add(name, values)
        else:
            for info in infos:
                for key, value in info.items():
                    name = self._log_name(key)
                    v = None if name is None else _finite_float(value)
                    if name is not None and v is not None:
                        self._add(name, np.array([v]))
        if dones is not None:
            for i in np.flatnonzero(dones):
                reason = str(infos[i].get("termination_reason", "") or "")
                self._add("quadslam_episode/failure_rate", np.array([1.0 if reason else 0.0]))
                self.reasons[_slug(reason) if reason else "time_limit"] += 1
        return True

    def _on_rollout_end(self) -> None:
        """Merge the sums into the logger's running means (as ``record_mean`` per value)."""
        logger = self.logger
        for name, total in self._sums.items():
            count = self._counts[name]
            old, n = logger.name_to_value[name], logger.name_to_count[name]
            logger.name_to_value[name] = (old * n + total) / (n + count)
            logger.name_to_count[name] = n + count
            logger.name_to_excluded[name] = ()
        for name, count in self.reasons.items():
            logger.record(f"quadslam_episode/n_{name}", count)
        self._sums.clear()
        self._counts.clear()


class TqdmProgressCallback(BaseCallback):
    """``tqdm`` progress bar over the training timesteps, with the recent mean episode return.

    Args:
        desc: Bar label.
        mininterval: Minimum seconds between bar redraws.
    """

    def __init__(self, desc: str = "training", mininterval: float = 0.5) -> None:
        super().__init__(0)
        self.desc = desc
        self.mininterval = mininterval
        self.pbar: tqdm | None = None
        self._last_postfix = 0.0

    def _on_training_start(self) -> None:
        total = int(self.locals["total_timesteps"]) - int(self.model.num_timesteps)
        self.pbar = tqdm(
            total=total,
            unit="step",
            unit_scale=True,
            desc=self.desc,
            file=sys.stderr,
            mininterval=self.mininterval,
            dynamic_ncols=True,
        )

    def _on_step(self) -> bool:
        assert self.pbar is not None
        self.pbar.update(self.training_env.num_envs)
        now = time.monotonic()
        if now - self._last_postfix > 2.0:
            self._last_postfix = now
            buf = self.model.ep_info_buffer
            if buf:
                self.pbar.set_postfix(
                    ep_return=f"{np.mean([e['r'] for e in buf]):.1f}",
                    ep_len=f"{np.mean([e['l'] for e in buf]):.0f}",
                    refresh=False,
                )
        return True

    def _on_training_end(self) -> None:
        if self.pbar is not None:
            self.pbar.refresh()
            self.pbar.close()
            self.pbar = None


class StopWhenSet(BaseCallback):
    """End ``learn`` at the next environment step once ``event`` is set (SB3 stops when a
    callback's ``_on_step`` returns False; the PPO update under way finishes first)."""

    def __init__(self, event: threading.Event) -> None:
        super().__init__()
        self.event = event

    def _on_step(self) -> bool:
        return not self.event.is_set()


class SaveVecNormalizeCallback(BaseCallback):
    """Save the training ``VecNormalize`` statistics (use as ``callback_on_new_best``): SB3's
    pickle at ``path`` and the arrays beside it (``.npz``), written atomically together.

    Args:
        path: File to write (e.g. ``run/eval/best_vecnormalize.pkl``).
    """

    def __init__(self, path: Path) -> None:
        super().__init__(0)
        self.path = Path(path)

    def _on_step(self) -> bool:
        vec_normalize = self.model.get_vec_normalize_env()
        if vec_normalize is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            norm = Normalization.from_vec_normalize(vec_normalize)
            atomic_produce_all(
                [
                    (self.path, lambda tmp: vec_normalize.save(str(tmp))),
                    (self.path.with_suffix(".npz"), lambda tmp: write_normalization(tmp, norm)),
                ]
            )
        return True


class AtomicCheckpointCallback(CheckpointCallback):
    """SB3's ``CheckpointCallback`` with a checkpoint's files written atomically together.

    All of them (a replay buffer if asked, the ``VecNormalize`` statistics and the policy's
    weights as arrays and SB3's pickle, the model zip) are written under temporary names first
    and then moved into place, the zip last: a checkpoint
    whose zip exists is complete, and a save that fails (a kill, a full disk) leaves no file
    under a checkpoint's name.
    """

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq != 0:
            return True
        model: Any = self.model
        items: list[tuple[Path, Any]] = []
        if self.save_replay_buffer and getattr(model, "replay_buffer", None) is not None:
            path = Path(self._checkpoint_path("replay_buffer_", extension="pkl"))
            items.append((path, lambda tmp: model.save_replay_buffer(tmp)))
        zip_path = Path(self._checkpoint_path(extension="zip"))
        # The statistics and policy as arrays and pickles, the zip last (safe_files.save_files).
        saved = save_files(model, zip_path, zip_path.parent.parent, self.save_vecnormalize)
        atomic_produce_all([*items, *saved])
        return True


class AtomicEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` with ``evaluations.npz`` and ``best_model.zip`` written
    atomically.

    SB3 writes both in place (``np.savez``, ``model.save``); here it writes them into a hidden
    staging folder beside them, and each is moved into place after the evaluation that wrote
    it; a new best model's weights are written as arrays (``best_policy.npz``) before its zip
    lands. Takes the arguments of ``EvalCallback``; call :meth:`clean_up` when training ends
    (also after an interruption).
    """

    def __init__(
        self,
        eval_env: Any,
        *,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        **kwargs: Any,
    ) -> None:
        self._log_dir = None if log_path is None else Path(log_path)
        self._best_dir = None if best_model_save_path is None else Path(best_model_save_path)
        home = self._log_dir or self._best_dir
        self._stage = None if home is None else home / ".staging"
        stage = None if self._stage is None else str(self._stage)
        super().__init__(
            eval_env,
            log_path=stage if log_path is not None else None,
            best_model_save_path=stage if best_model_save_path is not None else None,
            **kwargs,
        )

    def _init_callback(self) -> None:
        super()._init_callback()
        for folder in (self._log_dir, self._best_dir):
            if folder is not None:
                folder.mkdir(parents=True, exist_ok=True)

    def _on_step(self) -> bool:
        continue_training = super()._on_step()
        best = None if self._stage is None else self._stage / "best_model.zip"
        if self._best_dir is not None and best is not None and best.exists():
            model = self.model  # a new best: its weights as arrays, before its zip lands
            atomic_produce(self._best_dir / "best_policy.npz", lambda t: write_policy(t, model))
        if self._stage is not None:
            for name, folder in (
                ("evaluations.npz", self._log_dir),
                ("best_model.zip", self._best_dir),
            ):
                staged = self._stage / name
                if folder is not None and staged.exists():
                    commit(staged, folder / name)
        return bool(continue_training)

    def clean_up(self) -> None:
        """Remove the staging folder (what is in it was never published)."""
        if self._stage is not None:
            shutil.rmtree(self._stage, ignore_errors=True)
