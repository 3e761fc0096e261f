"""Reports: matplotlib figures (:mod:`.figures`), the paper's tables as CSV (:mod:`.tables`) and the self-contained
HTML report page with its headless-browser check (:mod:`.page`). Submodules are imported on use (matplotlib is
heavy)."""

__all__: list[str] = []
