"""dm_control tasks, one module per domain; each module has a `SUITE` of tagged task constructors."""
