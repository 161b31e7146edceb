"""Load a trained run back as a policy on raw env observations, without running its files.

:func:`load_model` turns a run folder (or a model ``.zip`` of one) into a :class:`TrainedPolicy`
whose ``predict`` takes the *raw* env observation, applying the same ``VecNormalize``
statistics and residual wrapper as in training. It never unpickles unless told to: the SB3
model is rebuilt from the run's plain ``config.yaml`` (algorithm, policy, its keyword
arguments) and the spaces and weights of ``policy.npz``, the statistics from
``vecnormalize.npz`` (:mod:`agents.rl.saved.safe_files`). SB3's ``model.zip`` and
``vecnormalize.pkl`` hold pickles, which run whatever code they name when read: they are read
only with ``trust_pickle=True`` (``quadslam evaluate --trust-pickle``), for a run folder saved
before the arrays existed or a bare SB3 zip; ``quadslam convert-run``
(:func:`agents.rl.convert.convert_run`) writes the arrays of such a folder once.
"""

from __future__ import annotations

import inspect
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
from agents.rl.building import policy_arguments
from agents.rl.hyperparams import algorithms, parse_normalize, resolve_settings
from agents.rl.lane_share import ACTOR_KEY
from agents.rl.saved.manifest import verify_run
from agents.rl.saved.run_folder import find_run_dir, read_run_config, safe_paths, vecnormalize_path
from agents.rl.saved.safe_files import (
    Normalization,
    PolicyFile,
    SafeFileError,
    read_normalization,
    read_policy,
)
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
        normalization: The ``VecNormalize`` statistics
            (:class:`agents.rl.saved.safe_files.Normalization`) or ``None``.
        controller: DF-LQR controller for residual runs, else ``None``.
        scale: (4,) residual scale for residual runs, else ``None``.
    """

    def __init__(
        self,
        model: Any,
        algo: str,
        config: dict[str, Any] | None = None,
        normalization: Normalization | None = None,
        controller: DFLQRPolicy | LookAtPolicy | None = None,
        scale: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.algo = algo
        self.config = config
        self.normalization = normalization
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
        norm = self.normalization
        if norm is None:
            model_obs = batch
        else:  # a privileged critic's statistics are per entry: the actor's alone here
            model_obs = norm.normalize_obs(
                batch, ACTOR_KEY if isinstance(norm.obs_rms, dict) else None
            )
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
        if self.normalization is not None:
            extras.append("VecNormalize")
        if self.controller is not None and self.scale is not None:
            extras.append(f"residual_dflqr(scale={self.scale.tolist()})")
        return f"TrainedPolicy({self.algo}{', ' if extras else ''}{', '.join(extras)})"


# ---------------------------------------------------------------------------- without pickle
def rebuild_model(config: dict[str, Any], weights: PolicyFile, source: Path) -> Any:
    """The SB3 model a run's ``config.yaml`` describes, on the spaces and with the weights of
    its policy file (``source``, named in errors); nothing is unpickled.

    The algorithm is constructed as SB3's own ``load`` does, without an env
    (``_init_setup_model=False``, then the spaces, then ``_setup_model``), with the run's
    algorithm arguments (``use_sde`` among them: it shapes the policy) on the CPU; an off-policy
    algorithm gets a replay buffer of one transition (nothing is collected). A run of the sbx
    backend (``backend: sbx``) is rebuilt as SB3's torch PPO too: its ``policy.npz`` holds the
    weights in that policy's layout (:func:`agents.rl.sbx_backend.torch_layout`), and sbx is
    not needed.

    Raises:
        agents.rl.saved.safe_files.SafeFileError: The weights are another algorithm's or policy
            class's, or do not fit the policy the config describes.
    """
    algo = config["algo"]
    if weights.algo != algo:
        raise SafeFileError(
            f"{source}: the weights of a {weights.algo.upper()} model, but the run's config.yaml "
            f"names {algo!r}"
        )
    settings = resolve_settings(algo, config["hyperparams"])
    policy, policy_kwargs = policy_arguments(settings)
    cls: Any = algorithms()[algo]  # SB3's torch class, for the sbx backend too (torch layout)
    kwargs = {**settings["algo_kwargs"], "device": "cpu"}
    if settings["backend"] == "sbx":
        kwargs["use_sde"] = False  # never with sbx (refused); its policy.npz is SB3's layout
    if "buffer_size" in inspect.signature(cls).parameters:
        kwargs["buffer_size"] = 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = cls(policy, None, policy_kwargs=policy_kwargs, _init_setup_model=False, **kwargs)
        model.observation_space, model.action_space = (
            weights.observation_space,
            weights.action_space,
        )
        model.n_envs = 1
        if getattr(model, "target_entropy", None) == "auto":  # SAC would ask its env for it
            model.target_entropy = -float(np.prod(weights.action_space.shape or ()))
        model._setup_model()
    if type(model.policy).__name__ != weights.policy_class:
        raise SafeFileError(
            f"{source}: the weights of a {weights.policy_class}, but the run's config.yaml "
            f"builds a {type(model.policy).__name__}"
        )
    import torch

    state = {name: torch.as_tensor(np.array(arr)) for name, arr in weights.tensors.items()}
    try:
        model.policy.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        reason = " ".join(str(exc).split())[:300]
        raise SafeFileError(
            f"{source}: its weights do not fit the {algo.upper()} policy the run's config.yaml "
            f"describes ({reason})"
        ) from None
    model.num_timesteps = weights.num_timesteps
    if model.use_sde:  # as SB3's load: a gSDE exploration matrix on this device
        model.policy.reset_noise()
    return model


# ---------------------------------------------------------------------------- trusted pickles
def _algo_hint(zip_path: Path) -> str | None:
    """Guess the algorithm from the policy class recorded in an SB3 zip (read as JSON)."""
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


def load_pickled_model(zip_path: Path, algo: str | None) -> tuple[Any, str]:
    """``(model, algo)`` from SB3's ``model.zip``, by ``<Algorithm>.load``.

    This unpickles the zip's ``data``, which runs whatever code it names: call it only for a
    file you trust (``trust_pickle=True``).

    Raises:
        ValueError: Not an SB3 model of a known algorithm.
    """
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


def load_pickled_stats(path: Path) -> Normalization:
    """The statistics of SB3's ``vecnormalize.pkl``, by unpickling it (runs whatever code the
    file names: only for a file you trust, ``trust_pickle=True``).

    Raises:
        ValueError: Unreadable, or not a ``VecNormalize`` pickle.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with path.open("rb") as fh:
            vec_normalize = pickle.load(fh)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read the VecNormalize statistics ({exc})") from exc
    if not isinstance(vec_normalize, VecNormalize):
        raise ValueError(f"{path}: not a VecNormalize file (got {type(vec_normalize).__name__})")
    return Normalization.from_vec_normalize(vec_normalize)


# ---------------------------------------------------------------------------- loading
def _locate(path: Path) -> tuple[Path | None, Path]:
    """``(run folder or None, model zip)`` of a run folder or a zip.

    Raises:
        FileNotFoundError: A folder with neither ``policy.npz`` nor ``model.zip``.
        ValueError: A folder with one of them but no readable ``config.yaml``.
    """
    if not path.is_dir():
        return find_run_dir(path), path
    zip_path = path / "model.zip"
    if not zip_path.is_file() and not safe_paths(zip_path, path)[0].is_file():
        ckpts = sorted((path / "checkpoints").glob("*.zip"))
        hint = f"; checkpoints: {[c.name for c in ckpts]}" if ckpts else ""
        raise FileNotFoundError(f"{path}: run folder without policy.npz or model.zip{hint}")
    if read_run_config(path) is None:
        raise ValueError(
            f"{path}: a model found but config.yaml is missing or unreadable (not a run folder "
            "written by quadslam train)"
        )
    return path, zip_path


def _untrusted(path: Path, run_dir: Path | None, missing: Path | None) -> ValueError:
    """The one-line refusal to unpickle, with what to do instead."""
    if run_dir is None or missing is None:
        return ValueError(
            f"{path}: a model .zip outside a run folder loads only by unpickling it, which runs "
            "any code it holds; if you trust who wrote it, pass --trust-pickle "
            "(trust_pickle=True; a sweep's trust_pickle: true)"
        )
    return ValueError(
        f"{path}: no {missing.relative_to(run_dir)} (a run saved before quadslam wrote its "
        "weights and statistics as arrays), and its SB3 zip and pickle run any code they hold "
        f"when read; if you trust who wrote it, convert it once: quadslam convert-run {run_dir} "
        "--trust-pickle (or read the pickles as they are: --trust-pickle)"
    )


def _load_files(
    path: Path, run_dir: Path, zip_path: Path, config: dict[str, Any], trust_pickle: bool
) -> tuple[Any, str, Normalization | None]:
    """The model and statistics of a run's ``zip_path``: from the arrays, or (trusted and
    without them) from the pickles; each file checked against the manifest first."""
    normalized = parse_normalize(config.get("hyperparams", {}).get("normalize", False)) is not None
    weights, stats = safe_paths(zip_path, run_dir)
    config_file = run_dir / "config.yaml"
    if weights.is_file():
        verify_run(run_dir, [config_file, weights, *([stats] if normalized else [])])
        model = rebuild_model(config, read_policy(weights), weights)
        if normalized and not stats.is_file():
            raise FileNotFoundError(f"{path}: the run used VecNormalize but {stats} is missing")
        return model, config["algo"], read_normalization(stats) if normalized else None
    if not trust_pickle:
        raise _untrusted(path, run_dir, weights)
    pkl = vecnormalize_path(zip_path, run_dir)
    verify_run(run_dir, [config_file, zip_path, *([pkl] if normalized else [])])
    model, algo = load_pickled_model(zip_path, config["algo"])
    if normalized and not pkl.is_file():
        raise FileNotFoundError(f"{path}: the run used VecNormalize but {pkl} is missing")
    return model, algo, load_pickled_stats(pkl) if normalized else None


def load_model(path: str | Path, env: gym.Env, *, trust_pickle: bool = False) -> TrainedPolicy:
    """Load a run folder or a model ``.zip`` as a policy for ``env``, without running code.

    A run folder gives its final model; a zip inside a run folder (``model.zip``,
    ``eval/best_model.zip``, ``checkpoints/model_<N>_steps.zip``) names that saved model.
    Either is rebuilt from the run's ``config.yaml`` and the weights and statistics saved as
    arrays beside the zip (:func:`agents.rl.saved.run_folder.safe_paths`); the zip itself is not
    read. Only with ``trust_pickle`` are SB3's zip and ``VecNormalize`` pickle read, when the
    arrays are missing (a run saved before they existed), and a bare zip outside a run folder
    is tried as the algorithm named in it, then PPO, SAC, TD3, without normalisation or
    wrapper: unpickling runs whatever code the files name. A run folder is first checked
    against its ``manifest.json`` (:func:`agents.rl.saved.manifest.verify_run`): a file that
    differs, or a file to be read that it does not list, is refused before anything is read;
    a folder without a manifest is loaded after a
    :class:`~agents.rl.saved.manifest.ManifestWarning`.

    Args:
        path: Run folder or ``.zip``.
        env: The evaluation env (raw ``QuadSLAMEnv`` observations and actions).
        trust_pickle: Read the pickles of a run without arrays, or a bare zip.

    Raises:
        FileNotFoundError: The path, or a run folder's model, does not exist.
        ValueError: Unreadable file, a run without arrays or a bare zip without
            ``trust_pickle`` (the message says how to convert it), or the model's
            observation/action shape differs from ``env``'s (the message names both).
        agents.rl.saved.manifest.ManifestError: A run folder's file differs from its manifest or is
            not listed (a ``ValueError``).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    run_dir, zip_path = _locate(path)
    config = read_run_config(run_dir) if run_dir else None
    norm: Normalization | None = None
    if config is None or run_dir is None:
        if not trust_pickle:
            raise _untrusted(path, None, None)
        model, algo = load_pickled_model(zip_path, None)
    else:
        model, algo, norm = _load_files(path, run_dir, zip_path, config, trust_pickle)

    obs_shape, act_shape = actor_space(model.observation_space).shape, model.action_space.shape
    env_obs, env_act = env.observation_space.shape, env.action_space.shape
    env_name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    if obs_shape != env_obs or act_shape != env_act:
        trained = f" (trained on {config['env_id']})" if config else ""
        raise ValueError(
            f"{path}: model observation/action shapes {obs_shape}/{act_shape}{trained} do not "
            f"match the env {env_name} observation/action shapes {env_obs}/{env_act}"
        )
    controller = scale = None
    if config is not None:
        _warn_if_env_differs(config, env)
        stats = None if norm is None else norm.obs_stats(ACTOR_KEY)  # a Box's: key unused
        if stats is not None and stats.mean.shape != env_obs:
            raise ValueError(
                f"{path}: VecNormalize statistics of shape {stats.mean.shape} do not match the "
                f"env {env_name} observation shape {env_obs}"
            )
        wrapper = parse_wrapper_spec(config.get("hyperparams", {}).get("wrapper"))
        if wrapper is not None:
            residual = ResidualDFLQR(env, **wrapper[1])
            controller, scale = residual.controller, residual.scale
    return TrainedPolicy(model, algo, config, norm, controller, scale)


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
