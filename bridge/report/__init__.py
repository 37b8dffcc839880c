"""What people see: tables, PNG figures, Allan and analysis reports, sweep pictures, Rerun views
and the served viewer.
"""
