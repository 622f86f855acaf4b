"""What a run writes beside its estimates: KPIs, report.md and plots, the rerun recording."""
