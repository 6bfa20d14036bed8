"""The run report: one self-contained HTML page with the run's figures, plots and a 3D viewer.

    from recon.report import Sources, build_report
    page = build_report(Sources(database=..., model=...), title="my run")
    Path("report.html").write_text(page.html)
"""

from recon.report.gather import Sources
from recon.report.page import Limits, Report, build_report

__all__ = ["Limits", "Report", "Sources", "build_report"]
