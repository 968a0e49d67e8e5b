"""Plain-text tables of a work-precision result (what ``vi-jax compare`` prints)."""


def _fmt(x, spec=".2e"):
    return "—" if x is None else format(x, spec)


def format_tables(result):
    """Plain-text tables of a result (what the command prints)."""
    lines = []
    for name, data in result["work_precision"].items():
        lines += [f"\nwork precision — {data['system']}, T = {data['T']:g} s (reference check "
                  f"{data['reference']['difference_from_rtol_10x']:.1e})",
                  f"{'peer':32s} {'setting':>24s} {'compile [s]':>11s} {'median [s]':>11s} {'error':>9s}"]
        for peer, rows in data["peers"].items():
            for r in rows:
                setting = f"N={r['n_steps']}" if "n_steps" in r else f"rtol={r['rtol']:.0e}"
                lines.append(f"{peer:32s} {setting:>24s} {r['compile_s']:11.2f} {r['median_s']:11.5f} {_fmt(r['error']):>9s}")
        goal = data["goal"]
        lines.append(f"goal ({goal['criterion']}): {'met' if goal['met'] else 'NOT met'}")
        for g in goal["accuracies"]:
            lines.append(f"  {g['accuracy']:.0e}: vi_jax {_fmt(g['vi_jax_s'], '.4f')} s ({g['vi_jax']}), "
                         f"diffrax {_fmt(g['diffrax_s'], '.4f')} s ({g['diffrax']}), ratio {_fmt(g['ratio'], '.1f')}")
    data = result["long_horizon"]
    if not data:
        return "\n".join(lines)
    lines += [f"\nlong horizon — {data['system']}, T = {data['T']:g} s",
              f"{'peer':32s} {'setting':>14s} {'median [s]':>11s} {'max dE/E':>9s} {'KN/scale':>9s} {'‖RᵀR−I‖':>9s}"]
    for peer, rows in data["peers"].items():
        for r in rows:
            setting = f"N={r['n_steps']}" if "n_steps" in r else f"rtol={r['rtol']:.0e}"
            lines.append(f"{peer:32s} {setting:>14s} {r['median_s']:11.3f} {_fmt(r['energy_error']):>9s} "
                         f"{_fmt(r['kelvin_noether_error']):>9s} {_fmt(r['group_drift']):>9s}")
    goal = data["goal"]
    lines.append(f"goal ({goal['criterion']}): {'met' if goal['met'] else 'NOT met'}")
    for g in goal["schemes"]:
        lines.append(f"  {g['peer']} (N={g['n_steps']}): {g['energy_error']:.2e} in {g['median_s']:.2f} s; best diffrax within that "
                     f"time{' (every run slower; its fastest)' if g.get('every_diffrax_run_slower') else ''} "
                     f"{_fmt(g['best_diffrax_energy_error_within_time'])} (ratio {_fmt(g['ratio'], '.2g')}); "
                     f"KN/scale {g['kelvin_noether_error']:.1e}")
    return "\n".join(lines)
