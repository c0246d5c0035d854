// One IIFE script (viewer.js) and one stylesheet (viewer.css) with fixed names: the C++ side
// inlines them into report.html and the page of `fascicle view` (src/report/report_writer.cpp).
import { defineConfig } from 'vite';

export default defineConfig({
  build: {
    outDir: 'dist',
    emptyOutDir: true,
    cssCodeSplit: false,
    lib: {
      entry: 'src/main.ts',
      name: 'FascicleViewer',
      formats: ['iife'],
      fileName: () => 'viewer.js',
      cssFileName: 'viewer',
    },
  },
});
