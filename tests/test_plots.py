"""Figures name their quantities with units and label every line."""


def test_figures_name_units_and_label_every_line(tmp_path):
    from types import SimpleNamespace

    from bogie_env.analysis import plots

    assert plots.param_label("Kpx") == "primary longitudinal stiffness Kpx (N/m)"
    assert plots.param_label("Csy").endswith("Csy (N s/m)")
    captured = {}
    real_save = plots.save

    def keep(fig, path, dpi=130):
        captured["axes"] = [(ax.get_xlabel(), [t.get_text() for t in ax.get_legend().get_texts()]) for ax in fig.axes
                            if ax.get_legend() is not None]  # fmt: skip
        return real_save(fig, path, dpi)

    curve = SimpleNamespace(param="Kpz", values=[4e5, 5e5, 6e5], critical_speed_kmh=[300.0, 350.0, 380.0])
    plots.save, saved = keep, plots.save
    try:
        plots.curves_figure([curve], 358.6, tmp_path / "c.png")
    finally:
        plots.save = saved
    (xlabel, legend), = captured["axes"]
    assert xlabel == "primary vertical stiffness Kpz (N/m)"
    assert legend == ["linear critical speed", "nominal bogie 358.6 km/h", "EN 14363 requirement 330 km/h"]
