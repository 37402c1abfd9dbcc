"""The TUI's widgets: each paints one part of a :class:`~hdeem_watch.tui.snapshot.NodeSnapshot`."""

from hdeem_watch.tui.widgets.calib import CalibPanel
from hdeem_watch.tui.widgets.channels import ChannelTable
from hdeem_watch.tui.widgets.groups import GroupsPanel
from hdeem_watch.tui.widgets.health import HealthBar
from hdeem_watch.tui.widgets.plots import PowerPlots
from hdeem_watch.tui.widgets.runs import RunsPanel

__all__ = ["CalibPanel", "ChannelTable", "GroupsPanel", "HealthBar", "PowerPlots", "RunsPanel"]
