"""Reading results back: leaderboards laid out like the paper's tables
(:mod:`~shapebench.boards.leaderboard`), their arithmetic (:mod:`~shapebench.boards.stats`),
costs (:mod:`~shapebench.boards.cost`), figures (:mod:`~shapebench.boards.figures`), the
paper's own numbers (:mod:`~shapebench.boards.paper`) and the HTML report
(:mod:`~shapebench.boards.html_report`).
"""
