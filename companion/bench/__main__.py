from companion.bench.companion_bench import main

main()
