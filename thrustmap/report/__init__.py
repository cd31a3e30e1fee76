"""Reports and figures of a thrust map: a self-contained HTML report and publication figures.

``data.build`` computes every number once; ``figures`` draws them (matplotlib); ``html`` writes
the report. Nothing here is imported by the CLI until a report or a figure is asked for.
"""
