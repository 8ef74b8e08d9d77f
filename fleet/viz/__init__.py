"""What people look at: the live table, progress lines, trajectory and load-test plots."""
