"""matplotlib for swarmctl's pictures (preview.png, mission.png, the replay's panels and plots)."""

from __future__ import annotations

from typing import Any


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed), with mathtext off: names drawn in
    titles and legends come from files and recordings (an area's file name, a mission's name, a
    recording's folder), and a `$` in one of them is drawn as written instead of failing the picture
    as a formula matplotlib cannot parse."""
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["text.parse_math"] = False
    import matplotlib.pyplot as plt

    return plt
