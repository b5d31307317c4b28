"""Writing results: ``solution.vtu`` for ParaView, ``summary.json`` and, for iterative
methods, ``convergence.png``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .discretize import Discretization
from .material import von_mises
from .solution import Solution, summary

_VTK_CELL = {2: "triangle", 3: "tetra"}


def mandel_to_tensor(sigma: np.ndarray) -> np.ndarray:
    """Mandel vectors ``(n, 4|6)`` to full symmetric tensors ``(n, 3, 3)``."""
    n = sigma.shape[0]
    t = np.zeros((n, 3, 3))
    r = 1.0 / np.sqrt(2.0)
    for i in range(3):
        t[:, i, i] = sigma[:, i]
    if sigma.shape[1] == 4:
        t[:, 0, 1] = t[:, 1, 0] = r * sigma[:, 3]
    else:
        t[:, 1, 2] = t[:, 2, 1] = r * sigma[:, 3]
        t[:, 0, 2] = t[:, 2, 0] = r * sigma[:, 4]
        t[:, 0, 1] = t[:, 1, 0] = r * sigma[:, 5]
    return t


def write_vtu(path: str | Path, disc: Discretization, sol: Solution) -> None:
    """Displacement, contact pressure/force (nodal); stress tensor, von Mises,
    xi and the plastic flag (per element)."""
    import meshio

    mesh = disc.mesh
    d = disc.dim
    points = mesh.points if d == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_nodes)])
    disp = sol.u if d == 3 else np.column_stack([sol.u, np.zeros(mesh.n_nodes)])
    pressure = np.zeros(mesh.n_nodes)
    pressure[disc.contact_nodes] = np.nan_to_num(sol.contact_pressure)
    force = np.zeros(mesh.n_nodes)
    force[disc.contact_nodes] = sol.contact_force
    cells = {
        "stress": mandel_to_tensor(sol.sigma).reshape(-1, 9),
        "von_mises": von_mises(sol.sigma),
        "xi": sol.xi,
        "plastic": sol.plastic.astype(np.int32),
    }
    meshio.write(
        Path(path),
        meshio.Mesh(
            points,
            [(_VTK_CELL[d], mesh.cells)],
            point_data={"displacement": disp, "contact_pressure": pressure, "contact_force": force},
            cell_data={k: [v] for k, v in cells.items()},
        ),
    )


def write_results(out_dir: str | Path, disc: Discretization, sol: Solution, extra: dict[str, Any] | None = None) -> dict:
    """Write ``solution.vtu`` and ``summary.json`` into ``out_dir``; returns the summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_vtu(out / "solution.vtu", disc, sol)
    data = summary(disc, sol)
    if sol.history:
        data["history"] = sol.history
    if extra:
        data.update(extra)
    (out / "summary.json").write_text(json.dumps(data, indent=2, default=json_default) + "\n")
    if sol.history:
        plot_convergence(out / "convergence.png", sol.history, f"{sol.method}: {sol.status.value}")
    return data


def plot_convergence(path: str | Path, history: list[dict[str, Any]], title: str = "") -> bool:
    """Plot the KKT residuals of an iteration history against the iteration.

    Each history row may hold ``residuals`` (a dict name -> value, one curve
    each) and ``kkt_worst``; rows are placed at their ``iteration`` (else their
    index). Returns False, writing nothing, when no row has residuals.
    """
    from matplotlib.figure import Figure

    rows = [h for h in history if isinstance(h.get("residuals"), dict) or "kkt_worst" in h]
    if not rows:
        return False
    its = [h.get("iteration", i) for i, h in enumerate(rows)]
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.add_subplot()
    curves = {name: [h.get("residuals", {}).get(name, np.nan) for h in rows]
              for name in sorted({k for h in rows for k in h.get("residuals", {})})}
    for name, vals in curves.items():
        ax.semilogy(its, _positive(vals), lw=1.0, label=name)
    if any("kkt_worst" in h for h in rows):
        worst = _positive([h.get("kkt_worst", np.nan) for h in rows])
        ax.semilogy(its, worst, "k--", lw=1.5, label="worst")
        if np.any(np.isfinite(worst)):  # show the worst residual's range, down to 1e-4 below its end
            ax.set_ylim(np.nanmin(worst) * 1e-4, np.nanmax(worst) * 10)
    ax.set_xlabel("iteration")
    ax.set_ylabel("relative KKT residual")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.savefig(Path(path), dpi=110)
    return True


def _positive(values: list[Any]) -> np.ndarray:
    """Values as floats with zeros and negatives as NaN (not drawn on a log axis)."""
    v = np.asarray(values, dtype=float)
    return np.where(v > 0, v, np.nan)


def json_default(obj: Any) -> Any:
    """JSON for numpy scalars and arrays (summary.json, the campaign store)."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")
