"""What people see: tables, PNG figures (all saved by ``figures.save_figure``), the validation
report, Allan and analysis reports, sweep pictures, Rerun views and the served viewer.
"""
