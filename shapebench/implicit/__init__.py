"""Neural implicit surfaces shared by the IGR, DeepSDF and MSC plugins (imports torch).

Only method modules import this package, and only when a method is used: plugin registration
never pulls torch in.
"""
