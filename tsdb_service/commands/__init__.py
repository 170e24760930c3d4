"""Commands apart from the backends: what an operator runs over whole stores.

``copy`` moves all history between backends; ``quantumleap`` imports what
QuantumLeap kept (its reader of QuantumLeap's tables, with that database's
own ``Dialect``). Each writes through the write seam and reads through the
read seam of a ``storage.Store``, as any client would, so it may import
``storage`` and the seams; ``storage`` never imports a command. The command
line around each (flags, printed reports) is in ``cli``.
"""
