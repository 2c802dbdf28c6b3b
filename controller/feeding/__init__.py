"""Auto-demand feeding: rations, the rail robot's state machine, the dispense ledger."""
