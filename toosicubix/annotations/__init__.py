"""The annotation file (version 1): the Pydantic schema and its loading (:mod:`.schema`), and the conversions to
and from the plain numpy model of :mod:`toosicubix.model` (:mod:`.convert`).

Nothing past this package imports pydantic: the solver sees the plain numpy model.
"""
