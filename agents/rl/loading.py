"""Load a trained run (or a bare SB3 zip) back as a policy on raw env observations.

:func:`load_model` turns a run folder (or a model ``.zip``) into a :class:`TrainedPolicy` whose
``predict`` takes the *raw* env observation, applying the same ``VecNormalize`` statistics and
residual wrapper as in training.
"""

from __future__ import annotations

import json
import pickle
import warnings
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from agents.control.dflqr import DFLQRPolicy
from agents.control.lookat import LookAtPolicy
from agents.rl.hyperparams import algorithms, parse_normalize
from agents.rl.lane_share import ACTOR_KEY
from agents.rl.manifest import verify_run
from agents.rl.run_folder import find_run_dir, read_run_config, vecnormalize_path
from agents.rl.wrappers import (
    ResidualDFLQR,
    parse_wrapper_spec,
    residual_action,
)


class TrainedPolicy:
    """A trained SB3 model with the training-time observation/action processing.

    ``predict`` takes the raw env observation, normalises it with the saved ``VecNormalize``
    statistics (if the run used them), queries the model and, for residual runs, adds the
    model's output as a residual to the DF-LQR action of the same raw observation — i.e. the
    action the env saw during training.

    Attributes:
        model: The SB3 algorithm instance.
        algo: Algorithm name.
        config: The run's ``config.yaml`` (``None`` for a bare ``.zip``).
        vec_normalize: ``VecNormalize`` statistics (``training=False``) or ``None``.
        controller: DF-LQR controller for residual runs, else ``None``.
        scale: (4,) residual scale for residual runs, else ``None``.
    """

    def __init__(
        self,
        model: Any,
        algo: str,
        config: dict[str, Any] | None = None,
        vec_normalize: Any = None,
        controller: DFLQRPolicy | LookAtPolicy | None = None,
        scale: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.algo = algo
        self.config = config
        self.vec_normalize = vec_normalize
        self.controller = controller
        self.scale = scale
        # An asymmetric actor-critic deploys its actor alone, on the plain observation.
        self.actor_only = hasattr(model.policy, "actor_action")

    @property
    def observation_space(self) -> gym.Space:
        """The observation space the policy acts on (the actor's, for an asymmetric one)."""
        return actor_space(self.model.observation_space)

    @property
    def action_space(self) -> gym.Space:
        """The model's action space."""
        return self.model.action_space

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict`` on raw observations (obs_dim,) or (n, obs_dim)."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        vec_normalize = self.vec_normalize
        if vec_normalize is None:
            model_obs = batch
        elif self.actor_only:  # the statistics of the actor's entry only
            model_obs = vec_normalize._normalize_obs(batch, vec_normalize.obs_rms[ACTOR_KEY])
        else:
            model_obs = vec_normalize.normalize_obs(batch)
        if self.actor_only:
            act = self.model.policy.actor_action(model_obs, deterministic=deterministic)
        else:
            act, state = self.model.predict(
                model_obs, state=state, episode_start=episode_start, deterministic=deterministic
            )
        act = np.asarray(act, dtype=np.float32)
        if self.controller is not None and self.scale is not None:
            base, _ = self.controller.predict(batch)
            act = residual_action(base, act, self.scale)
        return (act[0] if single else act), state

    def __repr__(self) -> str:
        extras = []
        if self.vec_normalize is not None:
            extras.append("VecNormalize")
        if self.controller is not None and self.scale is not None:
            extras.append(f"residual_dflqr(scale={self.scale.tolist()})")
        return f"TrainedPolicy({self.algo}{', ' if extras else ''}{', '.join(extras)})"


def _algo_hint(zip_path: Path) -> str | None:
    """Guess the algorithm from the policy class recorded in an SB3 zip."""
    try:
        with zipfile.ZipFile(zip_path) as archive:
            data = json.loads(archive.read("data").decode())
        text = json.dumps(data.get("policy_class", ""))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    for name in ("sac", "td3"):
        if f"stable_baselines3.{name}" in text:
            return name
    return None


def _load_sb3(zip_path: Path, algo: str | None) -> tuple[Any, str]:
    algos = algorithms()
    if algo is not None and algo not in algos:
        raise ValueError(f"{zip_path}: run config names algorithm {algo!r}; known: {list(algos)}")
    if not zipfile.is_zipfile(zip_path):
        raise ValueError(f"{zip_path}: not a stable-baselines3 model (.zip) file")
    hint = algo or _algo_hint(zip_path)
    order: list[str] = [*([hint] if hint else []), *([] if algo else ["ppo", "sac", "td3"])]
    errors = []
    for name in dict.fromkeys(order):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cls: Any = algos[name]
                return cls.load(zip_path, device="cpu"), name
        except Exception as exc:  # SB3 raises many kinds on a foreign/corrupt archive
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    raise ValueError(f"{zip_path}: cannot load as a stable-baselines3 model ({'; '.join(errors)})")


def _load_vecnormalize(path: Path) -> Any:
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with path.open("rb") as fh:
            vec_normalize = pickle.load(fh)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read the VecNormalize statistics ({exc})") from exc
    if not isinstance(vec_normalize, VecNormalize):
        raise ValueError(f"{path}: not a VecNormalize file (got {type(vec_normalize).__name__})")
    vec_normalize.training = False
    vec_normalize.norm_reward = False
    return vec_normalize


def load_model(path: str | Path, env: gym.Env) -> TrainedPolicy:
    """Load a run folder or a model ``.zip`` as a policy for ``env``.

    A run folder gives ``model.zip``; a zip inside a run folder (``model.zip``,
    ``eval/best_model.zip``, ``checkpoints/model_<N>_steps.zip``) uses that run's config and
    matching ``VecNormalize`` statistics; a bare zip is tried as the algorithm named in it,
    then PPO, SAC, TD3, without normalisation or wrapper. Like any pickle-based format, only
    load files you trust. A run folder is first checked against its ``manifest.json``
    (:func:`agents.rl.manifest.verify_run`): a file that differs, or a model or statistics file
    it does not list, is refused before anything is loaded; a folder without a manifest (an
    older run) is loaded after a :class:`~agents.rl.manifest.ManifestWarning`.

    Args:
        path: Run folder or ``.zip``.
        env: The evaluation env (raw ``QuadSLAMEnv`` observations and actions).

    Raises:
        FileNotFoundError: The path, or a run folder's ``model.zip``, does not exist.
        ValueError: Unreadable file, or the model's observation/action shape differs from
            ``env``'s (the message names both).
        agents.rl.manifest.ManifestError: A run folder's file differs from its manifest or is
            not listed (a ``ValueError``).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if path.is_dir():
        run_dir: Path | None = path
        zip_path = path / "model.zip"
        if not zip_path.is_file():
            ckpts = sorted((path / "checkpoints").glob("*.zip"))
            hint = f"; checkpoints: {[c.name for c in ckpts]}" if ckpts else ""
            raise FileNotFoundError(f"{path}: run folder without model.zip{hint}")
        if find_run_dir(zip_path) != path:
            raise ValueError(f"{path}: model.zip found but config.yaml is missing or unreadable")
    else:
        zip_path = path
        run_dir = find_run_dir(zip_path)
    config = read_run_config(run_dir) if run_dir else None
    if config is not None and run_dir is not None:  # before anything is unpickled
        needed = [run_dir / "config.yaml", zip_path]
        if parse_normalize(config.get("hyperparams", {}).get("normalize", False)) is not None:
            needed.append(vecnormalize_path(zip_path, run_dir))
        verify_run(run_dir, needed)
    model, algo = _load_sb3(zip_path, config["algo"] if config else None)

    obs_shape, act_shape = actor_space(model.observation_space).shape, model.action_space.shape
    env_obs, env_act = env.observation_space.shape, env.action_space.shape
    env_name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    if obs_shape != env_obs or act_shape != env_act:
        trained = f" (trained on {config['env_id']})" if config else ""
        raise ValueError(
            f"{path}: model observation/action shapes {obs_shape}/{act_shape}{trained} do not "
            f"match the env {env_name} observation/action shapes {env_obs}/{env_act}"
        )

    vec_normalize = controller = scale = None
    if config is not None and run_dir is not None:
        hp = config.get("hyperparams", {})
        _warn_if_env_differs(config, env)
        if parse_normalize(hp.get("normalize", False)) is not None:
            vn_path = vecnormalize_path(zip_path, run_dir)
            if not vn_path.is_file():
                raise FileNotFoundError(
                    f"{path}: the run used VecNormalize but {vn_path} is missing"
                )
            vec_normalize = _load_vecnormalize(vn_path)
            rms = vec_normalize.obs_rms
            shape = (rms[ACTOR_KEY] if isinstance(rms, dict) else rms).mean.shape
            if shape != env_obs:
                raise ValueError(
                    f"{vn_path}: VecNormalize statistics of shape {shape} do not match the env "
                    f"{env_name} observation shape {env_obs}"
                )
        wrapper = parse_wrapper_spec(hp.get("wrapper"))
        if wrapper is not None:
            residual = ResidualDFLQR(env, **wrapper[1])
            controller, scale = residual.controller, residual.scale
    return TrainedPolicy(model, algo, config, vec_normalize, controller, scale)


def _warn_if_env_differs(config: dict[str, Any], env: gym.Env) -> None:
    """Warn when evaluating on another env id or scenario than the run was trained on."""
    env_id = env.spec.id if env.spec is not None else None
    trained_id = config.get("env_id")
    scenario = getattr(env.unwrapped, "scenario", None)
    trained_scn = (config.get("scenario") or {}).get("name")
    diffs = []
    if env_id is not None and trained_id is not None and env_id != trained_id:
        diffs.append(f"env {env_id!r} (trained on {trained_id!r})")
    if scenario is not None and trained_scn is not None and scenario.name != trained_scn:
        diffs.append(f"scenario {scenario.name!r} (trained on {trained_scn!r})")
    if diffs:
        warnings.warn(
            "evaluating on a different setup than training: " + ", ".join(diffs),
            UserWarning,
            stacklevel=3,
        )


def actor_space(space: gym.Space) -> gym.Space:
    """The observation space a deployed policy reads: the ``obs`` entry of a privileged dict."""
    if isinstance(space, gym.spaces.Dict) and ACTOR_KEY in space.spaces:
        return space[ACTOR_KEY]
    return space
