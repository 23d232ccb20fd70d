"""`python -m epoet.eval.reference`: the converter's command (convert.py)."""

from epoet.eval.reference.convert import main

if __name__ == "__main__":
    main()
