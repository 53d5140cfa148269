"""Report section 6.5: SSID reduced-order models against the Guyan, IRS and C-B TAMs.

``replicate_section_6_5`` prints, for each retained DOF set (the report's 10, 12 and 16 DOFs):

* natural frequencies of the target modes: exact, SSID (undamped, from the identified M, K),
  Guyan, IRS and the Craig-Bampton TAM, with percent errors (Tables 6.21-6.23);
* fixed-interface eigenvalues of the analytical C-B TAM against those of the SSID model put
  into Craig-Bampton form, and the difference of the constraint-mode (boundary) stiffness
  (Tables 6.24-6.26, Figures 6.33-6.35);
* orthogonality of the SSID modes with each TAM's mass and cross-orthogonality against the
  full model's target modes (diagonal >= 0.9, off-diagonal < 0.1), beside the orthogonality
  of the full model's target modes themselves with that mass (the TAM's own limit).

How the report's unstated choices are made here (each can be overridden by an argument):

* target modes: the lowest full-model modes that the retained DOFs see well (IRS-expansion
  observability >= 0.8, :func:`expansion_observability`), one per retained DOF; the report's were
  "modes dominated by Z-translations" (Table 6.1): pass ``target_modes`` to use exactly those;
* SSID data: noise-free accelerances at the retained DOFs, forces at the interface DOFs
  (report section 6.1: active excitation at every interface DOF), ``n_lines`` lines from
  0.8 x the lowest target frequency to the geometric mean of the highest target and the next
  full-model mode (section 6.2.3: a band holding just the target modes works best),
  identified with ``identify_mck(solver="ls")`` (noise-free data, as in the report) and, with
  ``solvers=("ls", "bands")``, as the band-processed modal model holding the target modes
  (``identify_mck_modal`` with ``prefer_shapes``: an n-DOF least-squares fit to a band that
  holds more than n modes is not physical, and the report picked its roots by hand);
* C-B fixed-interface modes chosen for the targets by the scale-free selection of
  ``ssid.craig_bampton_tam.select_fixed_interface_modes``.

Each model's frequency in a table row is that of its mode paired one-to-one with the row's
target (on MAC x frequency ratio, with MAC >= 0.5 at the retained DOFs); '-' where none pairs.

Run on a stand-in (a 26-DOF beam on soft springs, ``stand_in_payload``) until
``ssid.models.payload`` exists:

    python bench/replicate_tams.py
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from ssid.correlate import (
    auto_mac,
    check_orthogonality,
    cross_orthogonality,
    modal_assurance,
    orthogonality,
    pair_modes_by_mac,
    pair_modes_by_mac_and_frequency,
)
from ssid.craig_bampton import craig_bampton_form
from ssid.craig_bampton_tam import craig_bampton_tam
from ssid.errors import IdentificationError, InputError
from ssid.frf import accelerance_from_model
from ssid.identify import identify_mck
from ssid.modal_model import identify_mck_modal
from ssid.tam import (
    dof_indices,
    guyan_reduce,
    irs_reduce,
    natural_frequencies_hz,
    normal_modes,
)

__all__ = ["default_targets", "expansion_observability", "replicate_section_6_5", "stand_in_payload"]


def expansion_observability(M: np.ndarray, K: np.ndarray, retained: Sequence[int]) -> np.ndarray:
    """How well the retained DOFs see each full-model mode, in [0, 1], (n,).

    The mass-weighted MAC between the mode and its IRS expansion from the retained DOFs,
    ``(phi^T M T phi_a)^2 / ((phi^T M phi)(phi_a^T T^T M T phi_a))``: near 1 for a global
    mode the measured DOFs describe, small for a local or rotation-dominated one. (IRS rather
    than Guyan: the static expansion alone already fails on the higher global modes.)
    """
    red = irs_reduce(M, K, retained)
    _, phi = normal_modes(M, K)
    ex = red.T @ phi[retained]
    num = np.einsum("ij,ik,kj->j", phi, M, ex) ** 2
    den = np.einsum("ij,ik,kj->j", phi, M, phi) * np.einsum("ij,ik,kj->j", ex, M, ex)
    return num / den


def default_targets(M: np.ndarray, K: np.ndarray, retained: Sequence[int],
                    threshold: float = 0.8) -> np.ndarray:
    """0-based target modes: the lowest ``n_a`` modes with :func:`expansion_observability` >=
    ``threshold`` (topped up with the best-seen others if too few), ascending."""
    score = expansion_observability(M, K, retained)
    n_a = len(retained)
    seen = np.flatnonzero(score >= threshold)[:n_a]
    if seen.size < n_a:
        rest = [k for k in np.argsort(-score) if k not in set(seen)]
        seen = np.concatenate([seen, rest[: n_a - seen.size]])
    return np.sort(seen.astype(int))


def _pct(a: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return 100.0 * np.abs(np.asarray(a) - ref) / np.abs(ref)


def _paired_frequencies(M_red, K_red, phi_t_a: np.ndarray, f_t: np.ndarray) -> np.ndarray:
    """Frequency (Hz) of the reduced model's mode paired with each target, NaN if none.

    One-to-one pairing on ``MAC x min(f, f_t) / max(f, f_t)``: MAC alone cannot tell apart
    targets that look alike at the retained DOFs (spatial aliasing), their frequencies can.
    A pair needs MAC >= 0.5.
    """
    lam, phi = normal_modes(M_red, K_red)
    f = np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi)
    out = np.full(phi_t_a.shape[1], np.nan)
    for p in pair_modes_by_mac_and_frequency(modal_assurance(phi, phi_t_a), f, f_t, 0.5):
        out[p.analysis] = f[p.test]
    return out


def _freq_table(name: str, f_exact, columns: dict[str, np.ndarray]) -> list[str]:
    head = f"{'Exact':>10} " + " ".join(f"{k + ' (Hz)':>12} {'% err':>9}" for k in columns)
    lines = [f"Natural frequencies -- {name} ({len(f_exact)}-DOF TAMs; cf. Tables 6.21-6.23)", head]
    for r, fe in enumerate(f_exact):
        cells = []
        for f in columns.values():
            if f is None or not np.isfinite(f[r]):
                cells.append(f"{'-':>12} {'-':>9}")
            else:
                cells.append(f"{f[r]:>12.5g} {_pct(f[r], fe):>9.3e}")
        lines.append(f"{fe:>10.5g} " + " ".join(cells))
    return lines


def _identify(frf, solver: str, phi_t: np.ndarray, f_t: np.ndarray):
    """SSID model of ``frf`` by ``solver``: an ``identify_mck`` step-1 solver, or ``"bands"``
    (:func:`ssid.modal_model.identify_mck_modal` with the target modes kept first, as the
    report picked its band-processing roots by hand). Returns the result or the reason none."""
    try:
        if solver == "bands":
            return identify_mck_modal(frf, prefer_shapes=phi_t, prefer_freq_hz=f_t)
        return identify_mck(frf, solver=solver)
    except IdentificationError as exc:
        return str(exc)


def replicate_section_6_5(
    M: np.ndarray,
    K: np.ndarray,
    C: np.ndarray,
    dofs: Sequence[str],
    interface_dofs: Sequence[str],
    retained_sets: dict[str, list[str]],
    *,
    target_modes: dict[str, list[int]] | None = None,
    bands_hz: dict[str, tuple[float, float]] | None = None,
    n_lines: int = 1024,
    solvers: Sequence[str] = ("ls",),
) -> str:
    """Tables of section 6.5 for each retained DOF set; returns the text (also fit to print).

    Parameters
    ----------
    M, K, C : (n, n)
        Full analytical model (kg, N/m, N s/m).
    dofs : sequence of str, (n,)
    interface_dofs : sequence of str
        Interface DOFs (shaker inputs of the SSID data, boundary of the C-B models); each must
        be in every retained set.
    retained_sets : {name: labels}
        E.g. ``{"10-DOF": [...], "12-DOF": [...], "16-DOF": [...]}``.
    target_modes : {name: 1-based mode numbers}, optional
        Overrides :func:`default_targets` (one per retained DOF).
    bands_hz : {name: (f_min, f_max)}, optional
        SSID band per set (default: see the module notes).
    n_lines : int
        Frequency lines of the SSID data.
    solvers : sequence of str
        One SSID model per entry, each compared with the TAMs: an ``identify_mck`` solver
        (``"ls"``, the report's, exact on noise-free data when the band holds as many modes
        as DOFs, ~50x faster than ``"ml"`` here) or ``"bands"`` (the band-processed modal
        model holding the target modes, ``identify_mck_modal``).
    """
    M = np.asarray(M, dtype=float)
    K = np.asarray(K, dtype=float)
    f_all = natural_frequencies_hz(M, K)
    _, phi_all = normal_modes(M, K)
    out: list[str] = []
    for name, labels in retained_sets.items():
        t0 = time.perf_counter()
        a = dof_indices(dofs, labels)
        missing = [d for d in interface_dofs if d not in labels]
        if missing:
            raise ValueError(f"{name}: interface DOF {missing[0]!r} is not retained")
        b = dof_indices(dofs, interface_dofs)
        nb_pos = dof_indices(labels, interface_dofs)  # boundary within the retained set
        if target_modes and name in target_modes:
            targets = np.asarray(target_modes[name], dtype=int) - 1
        else:
            targets = default_targets(M, K, a)
        f_t = f_all[targets]
        phi_t = phi_all[np.ix_(a, targets)]

        # SSID reduced-order models from noise-free accelerances at the retained DOFs.
        above = f_all[f_all > f_t.max() * (1 + 1e-9)]
        top = np.sqrt(f_t.max() * above[0]) if above.size else 1.1 * f_t.max()
        lo, hi = (bands_hz or {}).get(name, (0.8 * f_t[f_t > 0].min(), top))
        frf = accelerance_from_model(M, C, K, list(dofs), np.linspace(lo, hi, n_lines),
                                     list(labels), list(interface_dofs))
        ssid = {f"SSID {s}": _identify(frf, s, phi_t, f_t) for s in solvers}
        modes = {}  # physical SSID models' normal modes
        f_ssid = {}
        for k, r in ssid.items():
            f_ssid[k] = np.full(targets.size, np.nan)
            if isinstance(r, str):
                continue
            try:
                modes[k] = normal_modes(r.M, r.K)[1]
                f_ssid[k] = _paired_frequencies(r.M, r.K, phi_t, f_t)
            except np.linalg.LinAlgError:  # M not positive definite: no normal modes
                pass

        guyan = guyan_reduce(M, K, a)
        irs = irs_reduce(M, K, a)
        cb = craig_bampton_tam(M, K, a, b, targets=targets)
        tams = {"Guyan": guyan, "IRS": irs, "C-B": cb.reduced}
        cols = {**f_ssid, **{k: _paired_frequencies(v.M, v.K, phi_t, f_t) for k, v in tams.items()}}
        out += _freq_table(name, f_t, cols)
        out.append(f"  target modes (1-based): {', '.join(str(t + 1) for t in targets)}; SSID band "
                   f"{lo:.4g}-{hi:.4g} Hz, {n_lines} lines, inputs {', '.join(interface_dofs)}; "
                   f"models' modes paired with targets by MAC x frequency ratio")
        am = auto_mac(phi_t)
        np.fill_diagonal(am, 0.0)
        if am.max() > 0.9:  # the set cannot tell these targets apart
            i, j = np.unravel_index(np.argmax(am), am.shape)
            out.append(f"  spatial aliasing: targets {targets[i] + 1} and {targets[j] + 1} have "
                       f"auto-MAC {am[i, j]:.2f} at these DOFs")
        for k, r in ssid.items():
            for msg in [r] if isinstance(r, str) else r.warnings:
                out.append(f"  {k}: {msg}")

        # Fixed-interface eigenvalues: analytical C-B TAM vs each SSID model in C-B form.
        form_cb = craig_bampton_form(cb.reduced.M, cb.reduced.K, nb_pos)
        out.append("")
        out.append(f"Fixed-interface eigenvalues -- {name} (cf. Tables 6.24-6.26)")
        forms = {}
        for k in modes:
            try:
                forms[k] = craig_bampton_form(ssid[k].M, ssid[k].K, nb_pos)
            except InputError as exc:  # e.g. an indefinite interior partition
                out.append(f"  {k} has no Craig-Bampton form: {exc}")
        out += [f"  {k}: not physical, no Craig-Bampton form" for k in ssid if k not in modes]
        if forms:
            out.append(f"{'C-B Lambda (rad/s)^2':>22} "
                       + " ".join(f"{k + ' Lambda':>22} {'% diff':>9}" for k in forms))
            for i, lc in enumerate(form_cb.eigenvalues):
                out.append(f"{lc:>22.4e} " + " ".join(
                    f"{v.eigenvalues[i]:>22.4e} {_pct(v.eigenvalues[i], lc):>9.3e}"
                    for v in forms.values()))
            kc = form_cb.boundary_stiffness
            for k, v in forms.items():
                ks = v.boundary_stiffness
                rel = np.linalg.norm(ks - kc) / np.linalg.norm(kc)
                diag = _pct(np.diag(ks), np.diag(kc))
                out.append(f"  {k} constraint-mode (boundary) stiffness: ||K_ssid - K_cb||_F / "
                           f"||K_cb||_F = {rel:.3e}; diagonal % diff "
                           f"{', '.join(f'{d:.3e}' for d in diag)}")

        # Orthogonality of the SSID modes with each TAM mass; cross-orthogonality with the
        # full model's target modes at the retained DOFs.
        for k, phi_ssid in modes.items():
            pairs = pair_modes_by_mac(modal_assurance(phi_ssid, phi_t), 0.5)
            ti = [p.test for p in pairs]
            ai = [p.analysis for p in pairs]
            out.append("")
            out.append(f"Orthogonality -- {name}: {k} modes with each TAM mass ({len(pairs)} of "
                       f"{len(targets)} paired by MAC >= 0.5)")
            out.append(f"{'TAM':>6} {'ortho max|off|':>15} {'xortho min|diag|':>17} "
                       f"{'xortho max|off|':>16} {'criterion':>10} {'exact modes max|off|':>21}")
            for t, v in tams.items():
                o = check_orthogonality(orthogonality(phi_ssid[:, ti], v.M), diag_min=0.0)
                x = check_orthogonality(cross_orthogonality(phi_ssid[:, ti], phi_t[:, ai], v.M))
                # The same check on the full model's own target modes: what the TAM mass
                # allows at best, so a FAIL there is the TAM's, not the identification's.
                e = check_orthogonality(orthogonality(phi_t, v.M), diag_min=0.0)
                ok = o.passed and x.passed
                out.append(f"{t:>6} {o.max_offdiag:>15.3e} {x.min_diag:>17.4f} "
                           f"{x.max_offdiag:>16.3e} {'pass' if ok else 'FAIL':>10} "
                           f"{e.max_offdiag:>21.3e}")
        out.append(f"  ({time.perf_counter() - t0:.1f} s)")
        out.append("")
    return "\n".join(out)


# ----------------------------------------------------------------------------------------------
# Stand-in for the payload simulator
# ----------------------------------------------------------------------------------------------


def stand_in_payload(n_elem: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """M, K, C (2 % modal damping) and labels of a stand-in: a beam on a soft suspension.

    A 1.5 m aluminium-like Euler-Bernoulli beam (EI 2000 N m^2, 2.7 kg/m, consistent mass),
    translation ``"<node>+Z"`` and rotation ``"<node>+RY"`` at each of ``n_elem + 1`` nodes,
    springs of 2000 and 3000 N/m to ground at its ends (rigid-body-like modes near 7 and
    13 Hz). Not the report's payload simulator (issue 3 builds that): only a model with
    omitted rotational DOFs that carry inertia, on which the TAMs differ as in section 6.5.
    """
    from ssid.modal import modal_damping_matrix

    n_node = n_elem + 1
    h = 1.5 / n_elem
    ei, rho_a = 2.0e3, 2.7
    ke = ei / h**3 * np.array([[12, 6 * h, -12, 6 * h], [6 * h, 4 * h * h, -6 * h, 2 * h * h],
                               [-12, -6 * h, 12, -6 * h], [6 * h, 2 * h * h, -6 * h, 4 * h * h]])
    me = rho_a * h / 420 * np.array([[156, 22 * h, 54, -13 * h], [22 * h, 4 * h * h, 13 * h, -3 * h * h],
                                     [54, 13 * h, 156, -22 * h], [-13 * h, -3 * h * h, -22 * h, 4 * h * h]])
    n = 2 * n_node
    M = np.zeros((n, n))
    K = np.zeros((n, n))
    for e in range(n_elem):
        idx = np.arange(2 * e, 2 * e + 4)
        M[np.ix_(idx, idx)] += me
        K[np.ix_(idx, idx)] += ke
    K[0, 0] += 2.0e3
    K[-2, -2] += 3.0e3
    C = modal_damping_matrix(M, K, np.full(n, 0.02))
    dofs = [f"{k}+{c}" for k in range(1, n_node + 1) for c in ("Z", "RY")]
    return M, K, C, dofs


def _z(nodes: Sequence[int]) -> list[str]:
    return [f"{k}+Z" for k in nodes]


def main() -> None:
    M, K, C, dofs = stand_in_payload()
    f = natural_frequencies_hz(M, K)
    print(f"stand-in model (beam, not the payload simulator): {len(dofs)} DOFs, "
          f"modes {f[0]:.3g} ... {f[-1]:.4g} Hz; interface 1+Z, 7+Z, 13+Z\n")
    sets = {  # growing sensor sets, as the report's 10, 12 and 16 DOFs
        "7-DOF": _z([1, 3, 5, 7, 9, 11, 13]),
        "9-DOF": _z([1, 2, 4, 6, 7, 8, 10, 12, 13]),
        "13-DOF": _z(range(1, 14)),
    }
    print(replicate_section_6_5(M, K, C, dofs, _z([1, 7, 13]), sets))


if __name__ == "__main__":
    main()
