"""Hyperparameters as Stable-Baselines3, CleanRL, SB3-Contrib and the RL Zoo name them, and the canter keys that
mean the same: an unknown key spelled as a peer spells it gets canter's name for it (`overrides.key_suggestion`)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from canter.config.algorithms import algorithm_names, reads_key

_SB3, _CLEANRL, _CONTRIB, _ZOO = "Stable-Baselines3", "CleanRL", "SB3-Contrib", "RL Zoo"
_TD3_DDPG = ("td3", "ddpg")
_READS_PPO = "; {s} reads it from ppo"
_OFF_POLICY = ("td3", "ddpg", "sac")


@dataclass(frozen=True)
class Readers:
    """The algorithms that read `key` (their `AlgorithmSpec.reads`), as the sections a user writes a peer name under:
    one that trains with another's keys (rpo with ppo's, trpo with ppo's rollout keys) is told the key it reads."""

    key: str


@dataclass(frozen=True)
class PeerName:
    """A hyperparameter as other libraries name it, and the canter keys that mean the same."""

    name: str
    sections: tuple[str, ...] | Readers | None  # the sections a user writes it under; None: any, or none at all
    keys: tuple[str, ...]  # "{s}": the section it was written under
    libraries: tuple[str, ...]
    note: str = ""  # said after the peer's name: where it sets several keys, or the key lives in another section

    def written_under(self) -> tuple[str, ...] | None:
        """The sections a user writes it under, `Readers` as the registered algorithms read the key (but the key's
        own section, where the peer's name is canter's: ppo.gamma is no unknown key)."""
        if not isinstance(self.sections, Readers):
            return self.sections
        key = self.sections.key
        own = key.partition(".")[0] if key.partition(".")[2] == self.name else None
        return tuple(algo for algo in algorithm_names() if algo != own and reads_key(algo, key))

    def note_under(self, section: str) -> str:
        return self.note.format(s=section)


# Users coming from these libraries write their names (`ppo.learning_rate`), which difflib matches to unrelated
# keys (`td3.learning_starts`). Only names whose meaning matches the canter key's doc string are listed: CleanRL's
# batch_size is the whole rollout and its num_minibatches a count, neither of them ppo.minibatch_size, and its sac
# policy_frequency takes that many actor steps at once, which canter's sac.policy_delay does not.
PEER_NAMES = (
    PeerName("total_timesteps", None, ("run.total_steps",), (_SB3, _CLEANRL)),
    PeerName("n_timesteps", None, ("run.total_steps",), (_ZOO,)),
    PeerName("num_envs", None, ("env.num_envs",), (_CLEANRL,)),
    PeerName("n_envs", None, ("env.num_envs",), (_SB3,)),
    PeerName("seed", None, ("run.seed",), (_SB3, _CLEANRL)),
    PeerName("env_id", None, ("env.id",), (_CLEANRL,)),
    PeerName("learning_rate", Readers("ppo.lr"), ("ppo.lr",), (_SB3, _CLEANRL)),
    PeerName("learning_rate", ("trpo",), ("trpo.critic_lr",), (_CONTRIB,), ", the critic's"),
    PeerName("learning_rate", _TD3_DDPG, ("{s}.actor_lr", "{s}.critic_lr"), (_SB3, _CLEANRL), ", which sets both"),
    PeerName(
        "learning_rate", ("sac",), ("sac.actor_lr", "sac.critic_lr", "sac.alpha_lr"), (_SB3,), ", which sets all three"
    ),
    PeerName("policy_lr", _OFF_POLICY, ("{s}.actor_lr",), (_CLEANRL,)),
    PeerName("q_lr", _TD3_DDPG, ("{s}.critic_lr",), (_CLEANRL,)),
    PeerName("q_lr", ("sac",), ("sac.critic_lr", "sac.alpha_lr"), (_CLEANRL,), ", which sets both"),
    PeerName("n_epochs", Readers("ppo.epochs"), ("ppo.epochs",), (_SB3,)),
    PeerName("update_epochs", Readers("ppo.epochs"), ("ppo.epochs",), (_CLEANRL,)),
    PeerName("batch_size", Readers("ppo.minibatch_size"), ("ppo.minibatch_size",), (_SB3,)),
    PeerName("clip_range", Readers("ppo.clip"), ("ppo.clip",), (_SB3,)),
    PeerName("clip_coef", Readers("ppo.clip"), ("ppo.clip",), (_CLEANRL,)),
    PeerName("num_steps", Readers("ppo.n_steps"), ("ppo.n_steps",), (_CLEANRL,)),
    PeerName("n_steps", Readers("ppo.n_steps"), ("ppo.n_steps",), (_CONTRIB,), _READS_PPO),
    PeerName("gamma", Readers("ppo.gamma"), ("ppo.gamma",), (_CLEANRL, _CONTRIB), _READS_PPO),
    PeerName("gae_lambda", Readers("ppo.gae_lambda"), ("ppo.gae_lambda",), (_CLEANRL, _CONTRIB), _READS_PPO),
    PeerName("normalize_advantage", Readers("ppo.norm_adv"), ("ppo.norm_adv",), (_SB3,)),
    PeerName("rpo_alpha", ("ppo", "rpo"), ("rpo.alpha",), (_CLEANRL,)),
    PeerName("target_kl", ("trpo",), ("trpo.max_kl",), (_CONTRIB,)),
    PeerName("cg_max_steps", ("trpo",), ("trpo.cg_iters",), (_CONTRIB,)),
    PeerName("line_search_max_iter", ("trpo",), ("trpo.line_search_iters",), (_CONTRIB,)),
    PeerName("line_search_shrinking_factor", ("trpo",), ("trpo.line_search_shrink",), (_CONTRIB,)),
    PeerName("n_critic_updates", ("trpo",), ("trpo.critic_epochs",), (_CONTRIB,)),
    PeerName("batch_size", ("trpo",), ("trpo.critic_minibatch_size",), (_CONTRIB,)),
    PeerName("policy_frequency", _TD3_DDPG, ("{s}.policy_delay",), (_CLEANRL,)),
    PeerName("exploration_noise", _TD3_DDPG, ("{s}.noise_std",), (_CLEANRL,)),
    PeerName("policy_noise", ("td3",), ("td3.target_noise",), (_CLEANRL,)),
    PeerName("target_policy_noise", ("td3",), ("td3.target_noise",), (_SB3,)),
    PeerName("target_noise_clip", ("td3",), ("td3.noise_clip",), (_SB3,)),
    PeerName("ent_coef", ("sac",), ("sac.alpha",), (_SB3,), "; its 'auto' is sac.autotune=true"),
)


def written_section(key: str) -> tuple[str, str]:
    """(section, name) of a key as a peer's user writes it; CleanRL's flags are dashed (--learning-rate)."""
    section, _, name = key.strip().lower().replace("-", "_").rpartition(".")
    return section, name


def peer_keys(key: str, known_keys: Iterable[str]) -> tuple[PeerName, list[str]] | None:
    """The canter keys (of `known_keys`) that `key`, written as another library names the hyperparameter, stands
    for; None where no library names it so."""
    section, name = written_section(key)
    known = set(known_keys)
    for peer in PEER_NAMES:
        sections = peer.written_under()
        if peer.name == name and (sections is None or section in sections):
            keys = [template.format(s=section) for template in peer.keys]
            if all(k in known for k in keys):
                return peer, keys
    return None
