"""Reading results back: leaderboards laid out like the paper's tables
(:mod:`~shapebench.boards.leaderboard`, from the runs :mod:`~shapebench.boards.selection` picks
and the splits :mod:`~shapebench.boards.splits` finds, written by
:mod:`~shapebench.boards.markdown` and :mod:`~shapebench.boards.tidy`, with the metric card of
:mod:`~shapebench.boards.cards`), their arithmetic (:mod:`~shapebench.boards.stats`),
costs (:mod:`~shapebench.boards.cost`), figures (:mod:`~shapebench.boards.figures`), the
paper's own numbers (:mod:`~shapebench.boards.paper`) and the HTML report
(:mod:`~shapebench.boards.html_report`).
"""
