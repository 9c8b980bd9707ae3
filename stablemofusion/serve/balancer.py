"""Replicas of `smf serve` behind HAProxy: the shipped configuration (``assets/deploy/haproxy.cfg``, docs/replicas.md)
for any number of replicas, and the environment it reads.

The configuration is a data file, used as it is: the balancer's address and the replicas' come from the
environment (``SMF_LISTEN``, ``SMF_REPLICA_1`` ...), and :func:`haproxy_config` only repeats its ``server`` lines
for more than two replicas.
"""

from __future__ import annotations

import re
from importlib import resources

from ..core.errors import SMFError

CONFIG = ("assets", "deploy", "haproxy.cfg")
_SERVER = re.compile(r'^(\s*)server r2 "\$\{SMF_REPLICA_2\}"(.*)$', re.M)


def shipped_config() -> str:
    """The text of the shipped HAProxy configuration (two replicas)."""
    return resources.files("stablemofusion").joinpath(*CONFIG).read_text(encoding="utf-8")


def haproxy_config(replicas: int = 2) -> str:
    """The shipped configuration for ``replicas`` replicas (2 or more): one ``server rK`` line per replica in each
    backend, reading ``SMF_REPLICA_K``."""
    if replicas < 2:
        raise SMFError(f"a balancer needs at least 2 replicas, got {replicas}")
    extra = lambda m: "".join(f'{m.group(1)}server r{k} "${{SMF_REPLICA_{k}}}"{m.group(2)}\n'  # noqa: E731
                              for k in range(2, replicas + 1)).rstrip("\n")
    return _SERVER.sub(extra, shipped_config())


def haproxy_env(listen: str, replicas: list[str]) -> dict[str, str]:
    """The variables the configuration reads: the balancer's ``host:port`` and each replica's."""
    return {"SMF_LISTEN": listen, **{f"SMF_REPLICA_{k}": a for k, a in enumerate(replicas, start=1)}}


__all__ = ["haproxy_config", "haproxy_env", "shipped_config"]
