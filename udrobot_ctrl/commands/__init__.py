"""CLI subcommands of the plant (model export, simulate)."""
