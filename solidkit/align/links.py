"""Yaws of captures nothing else aligns, from relative yaws between them (a 1-D rotation averaging).

Captures tens of metres from the camera position often match no capture of known yaw, but do
match each other (a metre or two apart), or share a sky (:mod:`solidkit.align.sky`). Their
relative yaws (:class:`Link`, ``yaw_b - yaw_a``) form a graph whose nodes are the unknown yaws
and whose "ground" node carries the absolute yaws (:class:`Link` with ``a = GROUND``): a link to
a capture of known yaw, and each capture's compass.

Links from few matches are sometimes grossly wrong (repeated facades: 15-21° off with 13-20
inliers on a virtual campaign), so the solution is the largest consistent set, not a mean:
every spanning tree of the graph (few nodes: exhaustive) fixes all yaws; it is scored by the
truncated chi-square of every link, ``sum min((r / sigma)^2, n_sigma^2)``, the compasses
included; the best tree's inliers (``|r| <= n_sigma sigma``) are refitted by weighted least
squares. Each node's yaw is reported leaving its own compass out (the caller fuses it with that
compass as an independent cue), with its 1-sigma from the normal matrix.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from solidkit.align.schema import wrap_deg

__all__ = ["GROUND", "Link", "LinkedYaw", "solve_links"]

GROUND = ""


@dataclass(frozen=True)
class Link:
    """``yaw_b - yaw_a = yaw_deg`` (1-sigma ``sigma_deg``); ``a == GROUND``: an absolute yaw of ``b``.

    ``street_lines``: the absolute yaw it carries is fixed by street lines alone (a yaw modulo 90°).
    """

    a: str
    b: str
    yaw_deg: float
    sigma_deg: float
    kind: str
    detail: str = ""
    street_lines: bool = False


@dataclass(frozen=True)
class LinkedYaw:
    """A node's yaw from the links without its own compass; ``anchors``: the absolute links (other than
    compasses) in its connected group; ``used``/``rejected``: the relative links kept and refused."""

    yaw_deg: float
    sigma_deg: float
    group: tuple[str, ...]
    anchors: tuple[Link, ...]
    compasses: tuple[str, ...]
    used: tuple[Link, ...] = field(default=())
    rejected: tuple[Link, ...] = field(default=())


def _tree_yaws(nodes: list[str], tree: tuple[Link, ...]) -> dict[str, float] | None:
    adj: dict[str, list[tuple[str, float]]] = {n: [] for n in [GROUND, *nodes]}
    for e in tree:
        adj[e.a].append((e.b, e.yaw_deg))
        adj[e.b].append((e.a, -e.yaw_deg))
    y = {GROUND: 0.0}
    stack = [GROUND]
    while stack:
        u = stack.pop()
        for v, d in adj[u]:
            if v not in y:
                y[v] = y[u] + d
                stack.append(v)
    return y if len(y) == len(nodes) + 1 else None


def _grounded(nodes: list[str], links: list[Link]) -> tuple[list[str], list[Link]]:
    """The nodes some chain of links ties to the ground, and the links among them."""
    reach, grew = {GROUND}, True
    while grew:
        grew = False
        for e in links:
            if (e.a in reach) != (e.b in reach):
                reach |= {e.a, e.b}
                grew = True
    return [n for n in nodes if n in reach], [e for e in links if e.b in reach]


def _least_squares(
    nodes: list[str], links: list[Link], start: dict[str, float], floor_deg: float
) -> tuple[dict[str, float], dict[str, float]] | None:
    """Weighted least squares of the nodes the links tie to the ground (others get no value)."""
    nodes, links = _grounded(nodes, links)
    if not nodes:
        return {}, {}
    idx = {n: i for i, n in enumerate(nodes)}
    A = np.zeros((len(nodes), len(nodes)))
    rhs = np.zeros(len(nodes))
    for e in links:
        w = 1.0 / max(e.sigma_deg, 0.02) ** 2
        pred = start[e.b] - start[e.a]
        m = pred + wrap_deg(e.yaw_deg - pred)  # unwrapped near the current solution
        for n, s in ((e.a, -1.0), (e.b, 1.0)):
            if n == GROUND:
                continue
            i = idx[n]
            rhs[i] += s * w * m
            for k, t in ((e.a, -1.0), (e.b, 1.0)):
                if k != GROUND:
                    A[i, idx[k]] += s * t * w
    try:
        cov = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0):
        return None
    y = cov @ rhs
    return ({n: float(y[i]) for n, i in idx.items()}, {n: math.sqrt(float(cov[i, i])) for n, i in idx.items()})


def _components(nodes: list[str], links: list[Link]) -> dict[str, tuple[str, ...]]:
    parent = {n: n for n in nodes}

    def find(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for e in links:
        if e.a != GROUND:
            parent[find(e.a)] = find(e.b)
    groups: dict[str, list[str]] = {}
    for n in nodes:
        groups.setdefault(find(n), []).append(n)
    return {n: tuple(sorted(groups[find(n)])) for n in nodes}


def solve_links(
    nodes: list[str], links: list[Link], *, n_sigma: float = 3.0, floor_deg: float = 0.3, max_links: int = 16
) -> dict[str, LinkedYaw]:
    """Yaws of ``nodes`` from ``links`` (module doc); nodes with no relative link kept get no entry.

    ``floor_deg``: no link is trusted below this sigma when testing consistency; ``max_links``:
    the most precise links kept for the exhaustive tree search (compasses always kept).
    """
    nodes = list(dict.fromkeys(nodes))
    links = [e for e in links if e.b in nodes and (e.a == GROUND or e.a in nodes) and e.a != e.b]
    nodes, links = _grounded(nodes, links)  # a node no chain of links ties to the ground has no yaw here
    compass = [e for e in links if e.kind == "compass"]
    others = sorted((e for e in links if e.kind != "compass"), key=lambda e: e.sigma_deg)
    links = compass + others[: max(max_links - len(compass), 0)]
    if not nodes or not others:
        return {}

    def z2(e: Link, y: dict[str, float]) -> float:
        return (wrap_deg(y[e.b] - y[e.a] - e.yaw_deg) / max(e.sigma_deg, floor_deg)) ** 2

    best, best_score = None, math.inf
    for tree in itertools.combinations(links, len(nodes)):
        y = _tree_yaws(nodes, tree)
        if y is None:
            continue
        score = sum(min(z2(e, y), n_sigma**2) for e in links)
        if score < best_score - 1e-9:
            best, best_score = y, score
    if best is None:
        return {}
    inliers = [e for e in links if z2(e, best) <= n_sigma**2]
    rejected = tuple(e for e in links if e not in inliers and e.kind != "compass")
    fit = _least_squares(nodes, inliers, best, floor_deg)
    if fit is None:
        return {}
    y_all, _ = fit
    relative = [e for e in inliers if e.a != GROUND]
    comp = _components(nodes, relative)
    out = {}
    for n in nodes:
        group = comp[n]
        used = tuple(e for e in relative if e.a in group)
        anchors = tuple(e for e in inliers if e.a == GROUND and e.kind != "compass" and e.b in group)
        if not used and not anchors:  # nothing links this node to another: its yaw would be its compass's own
            continue
        loo = [e for e in inliers if not (e.kind == "compass" and e.b == n)]
        sub = _least_squares(nodes, loo, {GROUND: 0.0, **y_all}, floor_deg)
        if sub is None:
            continue
        y, s = sub
        if n not in y:
            continue
        compasses = tuple(e.b for e in loo if e.kind == "compass" and e.b in group)
        out[n] = LinkedYaw(wrap_deg(y[n]), s[n], group, anchors, compasses, used, rejected)
    return out
