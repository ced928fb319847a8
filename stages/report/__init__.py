"""`accrue report`: the metric table, figures and rerun recording of a workflow's committed run.

    from stages.report.build import write_report
    summary = write_report(store, wf, out_dir)    # summary dict (summary.REPORT_KEYS) + "files"

Modules: data (read records from the store), summary (metrics and per-task numbers), plots (PNGs),
recording (.rrd), build (ties them together). Heavy imports (matplotlib, rerun) stay inside
functions so importing this package is cheap.
"""
