"""The coordinator's database: engine and migrations, tables, and the stores that own its SQL."""
