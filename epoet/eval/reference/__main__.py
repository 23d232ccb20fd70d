from epoet.eval.reference.convert import main

main()
