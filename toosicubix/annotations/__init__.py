"""The annotation file (version 1): the Pydantic schema and its loading (:mod:`.schema`).

Nothing past this package imports pydantic: the solver sees the plain numpy model of :mod:`toosicubix.model`.
"""
